"""Progress of a long phase on stderr, so that no phase of a command looks like a hang.

    from robomorph.core.progress import progress

    for window in progress(windows, "identified physics", unit="window"):
        ...

On a terminal this is a tqdm bar (counts, rate, time left) whose clock a background
thread refreshes every second, so it moves even while one slow item runs. In a log (stderr
not a terminal) tqdm's carriage-return redraws would pile up on one line, so it writes a
plain line instead, ``identified physics: 3/8 windows, 0.41 windows/s, 0:07 elapsed, ~0:12
left``, every ``ROBOMORPH_PROGRESS_SECONDS`` seconds (default 5) from the same thread (again
while one item runs), and a closing line when the phase took that long. A phase that ends
sooner says nothing: short commands stay quiet.

Torch-free and thread-based only, so every layer can use it; a phase nested in another
(a batch loop inside a sweep setting) reports on its own.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

T = TypeVar("T")

ENV_SECONDS = "ROBOMORPH_PROGRESS_SECONDS"
DEFAULT_SECONDS = 5.0


def interval() -> float:
    """Seconds between lines in a log: ``ROBOMORPH_PROGRESS_SECONDS`` (a positive number), else 5."""
    try:
        value = float(os.environ.get(ENV_SECONDS, DEFAULT_SECONDS))
    except ValueError:
        return DEFAULT_SECONDS
    return value if value > 0 else DEFAULT_SECONDS


def _clock(seconds: float) -> str:
    s = int(round(max(seconds, 0.0)))
    h, m, s = s // 3600, s // 60 % 60, s % 60
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class Phase:
    """A counted phase: ``with Phase("horizon sweep", total=8, unit="setting") as p: ... p.update()``.

    Args:
        desc: what runs, as the user would name it (the line's first words).
        total: how many items, or None when unknown (the line then gives the count only).
        unit: the item's name, singular (a plural ``s`` is added in lines).
        enabled: False says nothing at all (a caller's ``progress=False``).
    """

    def __init__(self, desc: str, total: int | None = None, unit: str = "item", enabled: bool = True,
                 initial: int = 0) -> None:
        self.desc, self.total, self.unit, self.enabled = desc, total, unit, enabled
        # initial: items done before this session (a resumed run), counted but not in the rate.
        self.n = self.initial = int(initial)
        self.note = ""  # appended to each log line after " | " (settable: e.g. a generator's rejections)
        # Settable: seconds left of a wall-clock cap (a trainer's max_time), or None; the time left shown is then the
        # sooner of the cap and the count's own estimate (20000 steps at 10 s/step under a 90 s cap end in 90 s).
        self.cap_left = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._bar = None
        self._started = time.monotonic()
        self._lines = 0

    def __enter__(self) -> Phase:
        self._started = time.monotonic()
        if not self.enabled:
            return self
        # Asked at entry, not import: a test or a caller may have replaced sys.stderr.
        if _isatty(sys.stderr):
            from tqdm.auto import tqdm  # noqa: PLC0415

            self._bar = tqdm(total=self.total, initial=self.initial, desc=self.desc, unit=self.unit, leave=False,
                             file=sys.stderr, dynamic_ncols=True)
        self._thread = threading.Thread(target=self._beat, name=f"progress: {self.desc}", daemon=True)
        self._thread.start()
        return self

    def update(self, n: int = 1) -> None:
        with self._lock:
            self.n += n
            if self._bar is not None:
                self._bar.update(n)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        if self._bar is not None:
            self._bar.close()
        elif self.enabled and self._lines and exc[0] is None:
            # Only a phase that already reported closes its report; a short one stays silent.
            elapsed = time.monotonic() - self._started
            self._write(f"{self.desc}: {self._count()} in {_clock(elapsed)} ({self._rate(elapsed)})")

    def line(self) -> str:
        """The log line of the phase now: counts, rate, elapsed and (with a total and a rate) time left."""
        elapsed = time.monotonic() - self._started
        # No rate before the first item: "0 windows/s" would read as a stall, not as a start.
        parts = [self._count(), *([self._rate(elapsed)] if self.n > self.initial else []), f"{_clock(elapsed)} elapsed"]
        left = elapsed / (self.n - self.initial) * (self.total - self.n) if self.total and self.n > self.initial else None
        cap = self.cap_left() if self.cap_left is not None else None
        if cap is not None:
            left = max(0.0, cap) if left is None else min(left, max(0.0, cap))
        if left is not None:
            parts.append(f"~{_clock(left)} left")
        return f"{self.desc}: " + ", ".join(parts) + (f" | {self.note}" if self.note else "")

    def _count(self) -> str:
        units = self.unit if self.total == 1 or (self.total is None and self.n == 1) else _plural(self.unit)
        return f"{self.n}/{self.total} {units}" if self.total is not None else f"{self.n} {units}"

    def _rate(self, elapsed: float) -> str:
        done = self.n - self.initial
        rate = done / elapsed if elapsed > 0 else 0.0
        return f"{rate:.3g} {_plural(self.unit)}/s" if rate >= 1 or not done else f"{elapsed / done:.3g} s/{self.unit}"

    def _beat(self) -> None:
        # On a terminal the bar's clock is refreshed every second; in a log a line every interval().
        wait = 1.0 if self._bar is not None else interval()
        while not self._stop.wait(wait):
            with self._lock:
                if self._bar is not None:
                    self._bar.refresh()
                else:
                    self._write(self.line())
                    self._lines += 1

    @staticmethod
    def _write(text: str) -> None:
        stream = sys.stderr
        stream.write(text + "\n")
        stream.flush()


def _plural(unit: str) -> str:
    return unit + ("es" if unit.endswith(("s", "sh", "ch", "x")) else "s")


def _isatty(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # a closed or stand-in stream
        return False


def progress(items: Iterable[T], desc: str, unit: str = "item", total: int | None = None,
             enabled: bool = True) -> Iterator[T]:
    """``items`` one by one, reported as a :class:`Phase` (``total`` defaults to ``len(items)`` when it has one)."""
    if total is None:
        try:
            total = len(items)  # type: ignore[arg-type]
        except TypeError:
            total = None
    with Phase(desc, total, unit, enabled) as phase:
        for item in items:
            yield item
            phase.update()
