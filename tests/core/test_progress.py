"""Progress of long phases: a line on stderr every few seconds in a log, even while one slow item runs."""

import io
import re
import sys
import threading
import time

import pytest

from robomorph.core.progress import ENV_SECONDS, Phase, interval, progress


class Stamped(io.TextIOBase):
    """A non-terminal stderr that records when each line arrived (as a log file would hold them)."""

    def __init__(self) -> None:
        self.lines: list[tuple[float, str]] = []
        self._lock = threading.Lock()
        self._partial = ""

    def isatty(self) -> bool:
        return False

    def write(self, text: str) -> int:
        with self._lock:
            self._partial += text
            *done, self._partial = re.split(r"[\r\n]", self._partial)
            now = time.monotonic()
            self.lines += [(now, line) for line in done if line.strip()]
        return len(text)

    def gaps(self, start: float, end: float) -> list[float]:
        """Seconds between consecutive lines, counting from ``start`` and up to ``end``."""
        times = [start, *(t for t, _ in self.lines if start <= t <= end), end]
        return [b - a for a, b in zip(times, times[1:])]


# Under load a 0.7 s item may take longer: either way of writing the rate is right.
RATE = r"[\d.]+ windows/s|[\d.]+ s/window"


def stamped(monkeypatch, seconds: str = "0.2") -> Stamped:
    """Replaces stderr for the rest of the test (in the test body: pytest's capture resets it after
    fixtures run) and sets the interval between lines."""
    stream = Stamped()
    monkeypatch.setattr(sys, "stderr", stream)
    monkeypatch.setenv(ENV_SECONDS, seconds)
    return stream


def test_a_slow_item_still_gets_lines_with_counts_rate_and_time_left(monkeypatch):
    stderr = stamped(monkeypatch)
    start = time.monotonic()
    for _ in progress(range(3), "identified physics", unit="window"):
        time.sleep(0.7)  # each item 3.5 intervals long: lines must come while it runs, not only after it
    end = time.monotonic()
    texts = [line for _, line in stderr.lines]
    assert max(stderr.gaps(start, end)) < 0.6
    assert any(re.fullmatch(r"identified physics: 0/3 windows, 0:0\d elapsed", t) for t in texts)  # no rate yet
    assert any(re.fullmatch(rf"identified physics: 2/3 windows, ({RATE}), 0:0\d elapsed, ~0:0\d left", t)
               for t in texts)
    assert re.fullmatch(rf"identified physics: 3/3 windows in 0:0\d \(({RATE})\)", texts[-1])


def test_a_short_phase_says_nothing_and_a_disabled_one_nothing_at_all(monkeypatch):
    stderr = stamped(monkeypatch)
    assert list(progress(range(5), "model", unit="batch")) == list(range(5))
    with Phase("control", total=2, unit="episode", enabled=False) as p:
        time.sleep(0.5)
        p.update(2)
    assert stderr.lines == []


def test_units_are_plural_and_slow_rates_read_as_seconds_per_item(monkeypatch):
    stderr = stamped(monkeypatch)
    with Phase("model", total=4, unit="batch") as p:
        p.update()
        time.sleep(0.3)
        assert p.line().startswith("model: 1/4 batches, ")
    with Phase("smoothing", total=None, unit="window") as p:
        p.update()
        time.sleep(11 * 0.1)  # one window in over a second: below 1 per second reads as seconds per window
        assert re.match(r"smoothing: 1 window, 1\.\d+ s/window, 0:01 elapsed$", p.line())


def test_a_phase_that_fails_does_not_claim_to_have_finished(monkeypatch):
    stderr = stamped(monkeypatch)
    with pytest.raises(RuntimeError):
        for i in progress(range(3), "horizon sweep", unit="setting"):
            time.sleep(0.3)
            if i == 1:
                raise RuntimeError("boom")
    assert stderr.lines and not any(" in 0:" in line for _, line in stderr.lines)


def test_the_interval_comes_from_the_environment_and_bad_values_fall_back(monkeypatch):
    monkeypatch.setenv(ENV_SECONDS, "2.5")
    assert interval() == 2.5
    for bad in ("soon", "0", "-3"):
        monkeypatch.setenv(ENV_SECONDS, bad)
        assert interval() == 5.0


def test_a_wall_clock_cap_bounds_the_time_left():
    """20000 steps at 10 s a step under a 90 s cap end with the cap, not in 55 hours; without steps done, the cap
    alone is the time left; a cap already spent says 0:00."""
    phase = Phase("training", 20000, "step", enabled=False)
    phase._started = time.monotonic() - 20.0  # private: the phase's clock, set back to make a rate of 10 s/step
    phase.n = 2
    assert re.fullmatch(r"training: 2/20000 steps, 10(\.\d+)? s/step, 0:20 elapsed, ~55:3\d:\d\d left", phase.line())
    phase.cap_left = lambda: 70.0
    assert re.fullmatch(r"training: 2/20000 steps, 10(\.\d+)? s/step, 0:20 elapsed, ~1:10 left", phase.line())
    phase.n = 0
    assert phase.line().endswith("0:20 elapsed, ~1:10 left")
    phase.cap_left = lambda: -3.0
    assert phase.line().endswith("~0:00 left")
    phase.cap_left = lambda: None
    assert phase.line() == "training: 0/20000 steps, 0:20 elapsed"
