"""What a newcomer waits for: ``make test`` or ``make demo`` on a fresh clone, the install included, timed.

    python benchmarks/newcomer.py test            # or: demo; both: test demo
    python benchmarks/newcomer.py test --commit HEAD~3 --keep /tmp/clone

Clones the committed code (``--commit``, default HEAD: uncommitted changes are not in a fresh
clone either) into a temporary folder, runs ``make install`` there (a new .venv, as a new user
gets), then ``make <target>``, each timed by the wall clock with the CPU time of the processes it
ran, and appends one row per target to ``results/benchmarks/newcomer.csv`` (with the command,
commit, date and machine) and prints it. The machine may be shared: each row records the load average too, the 1-minute load
just before the install (the other jobs' load) and its mean and maximum while the target ran (its own
processes included), sampled every few seconds. The make output goes to ``<clone>/make_<target>.log``;
``--keep`` keeps the clone (default: removed when the target passed).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import threading
import time

from common import REPO

from robomorph.core.results import ResultsCsv, provenance

CSV = os.path.join(REPO, "results", "benchmarks", "newcomer.csv")
TARGETS = ("test", "demo")


def _git(*args: str, cwd: str = REPO) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout.strip()


# Seconds between two samples of the load average while a target runs.
LOAD_EVERY = 5.0


class LoadSampler:
    """Samples the 1-minute load average every :data:`LOAD_EVERY` seconds in a thread, while in its block."""

    def __init__(self) -> None:
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="load sampler", daemon=True)

    def _run(self) -> None:
        while True:
            self.samples.append(os.getloadavg()[0])
            if self._stop.wait(LOAD_EVERY):
                return

    def __enter__(self) -> LoadSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    @property
    def mean(self) -> float:
        return sum(self.samples) / len(self.samples)


def _timed(command: list[str], cwd: str, log: str) -> tuple[float, float, int, LoadSampler]:
    """Runs ``command`` with its output in ``log``: (wall seconds, CPU seconds of its processes, exit code,
    the load average sampled meanwhile)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.monotonic()
    with open(log, "w") as out, LoadSampler() as load:
        rc = subprocess.run(command, cwd=cwd, stdout=out, stderr=subprocess.STDOUT).returncode
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return time.monotonic() - start, cpu, rc, load


def _summary(log: str) -> str:
    """pytest's closing line (``1373 passed, 6 skipped in ...``), the demo's (``written (minutes: data 2.2,
    training 3.2, evaluation 2.1):``) or the log's last line."""
    with open(log, errors="replace") as f:
        lines = [line.strip() for line in f if line.strip()]
    found = [line for line in lines if re.search(r"\d+ (passed|failed)", line) or line.startswith("written (minutes:")]
    text = (found or lines or [""])[-1]
    return text.strip("= ")


def run(targets: list[str], commit: str, keep: str | None) -> list[dict]:
    sha = _git("rev-parse", commit)
    clone = keep or tempfile.mkdtemp(prefix="robomorph-newcomer-")
    if os.path.exists(os.path.join(clone, ".git")):
        raise SystemExit(f"error: --keep {clone} already holds a clone; give an empty or new folder")
    subprocess.run(["git", "clone", "-q", "--no-local", REPO, clone], check=True)
    _git("checkout", "-q", sha, cwd=clone)
    load_before = os.getloadavg()[0]  # the other jobs' load, before this clone adds its own
    install = _timed(["make", "install"], clone, os.path.join(clone, "make_install.log"))
    if install[2] != 0:
        raise SystemExit(f"error: make install failed in {clone} (see make_install.log)")
    rows, writer = [], ResultsCsv(CSV, prov=provenance())
    for target in targets:
        log = os.path.join(clone, f"make_{target}.log")
        wall, cpu, rc, load = _timed(["make", target], clone, log)
        row = {"target": target, "commit": sha[:10], "install_s": round(install[0], 1), "run_s": round(wall, 1),
               "total_s": round(install[0] + wall, 1), "cpu_s": round(cpu, 1), "cores": os.cpu_count(),
               "exit_code": rc, "summary": _summary(log), "load_before": round(load_before, 2),
               "load_mean": round(load.mean, 2), "load_max": round(max(load.samples), 2)}
        writer.append(row)
        rows.append(row)
        print(f"make {target}: {row['total_s'] / 60:.1f} min with the install ({row['install_s']:.0f} s), "
              f"{row['run_s']:.0f} s of make {target}, CPU {row['cpu_s']:.0f} s on {row['cores']} cores, load average "
              f"{row['load_before']:.1f} before, {row['load_mean']:.1f} mean / {row['load_max']:.1f} max during it, "
              f"exit {rc}: {row['summary']}", flush=True)
    if keep is None and all(r["exit_code"] == 0 for r in rows):
        shutil.rmtree(clone, ignore_errors=True)
    else:
        print(f"clone kept: {clone}")
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("targets", nargs="+", choices=TARGETS, help="make targets to time, in order")
    p.add_argument("--commit", default="HEAD", help="the commit to clone (default HEAD)")
    p.add_argument("--keep", help="clone into this folder and keep it")
    args = p.parse_args(argv)
    rows = run(args.targets, args.commit, args.keep)
    print(f"appended to {os.path.relpath(CSV, REPO)}")
    return 0 if all(r["exit_code"] == 0 for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
