"""The industrial robot benchmark (KUKA KR300 R2500 ultra SE, Weigand et al.) as its trajectories.

Two files carry it, and they are not laid out alike:

- the **official** ``forward_identification_without_raw_data.mat`` (what ``nonlinear-benchmarks``'
  ``Industrial_robot`` downloads): 39,988 training and 3,636 test samples at 10 Hz, the test six
  trajectories of 606 samples, each from rest to rest; ``u[t]`` and ``y[t]`` are sampled together;
- the **shifted** copy ``forward_identification_without_raw_data_shifted.mat`` (in the
  ``Physics-Guided-Recurrent-State-Space-Neural-Networks`` clone): each 606-sample trajectory re-cut
  to 605 with ``u[t]`` beside ``y[t + 1]`` (:func:`shift`), train / val / test 36,300 / 3,630 /
  3,630; the validation part ends with 8 zero-padded torque samples, trimmed here.

:func:`load` reads the official file where one is found under the data folder, else the shifted
copy, and says which (:attr:`IndustrialBenchmark.layout`). Angles stay in degrees, as the
benchmark reports them. The validation split is cut from the training data by trajectory (the
copy's own ``val`` part; for the official file, its last six training trajectories).

Predictors read a trajectory as ``u`` (T, 6) and ``y`` (T, 6) and may use ``u[t]`` when they
predict ``y[t]``: in the official layout that input comes one sample after the motion it drives,
in the shifted one it drives it, so one regressor set serves both.
"""

from __future__ import annotations

import glob
import hashlib
import os
from dataclasses import dataclass

import numpy as np

from robomorph.core.errors import MissingInputError, RoboMorphError

OFFICIAL = "forward_identification_without_raw_data.mat"
SHIFTED = "forward_identification_without_raw_data_shifted.mat"
# Samples per trajectory in each layout (the official test is 6 x 606; the copy re-cut it to 605).
TRAJECTORY = {"official": 606, "shifted": 605}
DT = 0.1  # 10 Hz
N_VAL = 6  # validation trajectories cut from the official training data (the copy's own count)


class IndustrialDataError(RoboMorphError, ValueError):
    """A benchmark file that lacks the variables or the shape the benchmark defines."""


@dataclass(frozen=True)
class IndustrialBenchmark:
    """The benchmark's trajectories, by split, in one layout.

    Attributes:
        path: the .mat file read.
        layout: ``official`` or ``shifted`` (see the module's docstring).
        sha256: the file's digest (its version, for provenance).
        train, val, test: lists of ``(u, y)`` arrays, (T, 6) each: motor torques [N m] and joint
            angles [deg].
    """

    path: str
    layout: str
    sha256: str
    train: list
    val: list
    test: list

    @property
    def test_u(self) -> np.ndarray:
        """The test inputs as one sequence (the trajectories in order), as the file holds them."""
        return np.concatenate([u for u, _ in self.test])

    @property
    def test_y(self) -> np.ndarray:
        return np.concatenate([y for _, y in self.test])

    def describe(self) -> str:
        lengths = {k: sum(len(u) for u, _ in getattr(self, k)) for k in ("train", "val", "test")}
        return (f"{os.path.basename(self.path)} ({self.layout} layout, sha256 {self.sha256[:12]}): "
                f"train / val / test {len(self.train)} / {len(self.val)} / {len(self.test)} trajectories, "
                f"{lengths['train']} / {lengths['val']} / {lengths['test']} samples")


def shift(u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One official trajectory in the shifted copy's layout: ``u[t]`` beside ``y[t + 1]``
    (the first output and the last input are dropped)."""
    return u[:-1], y[1:]


def find(data: str) -> tuple[str, str]:
    """The benchmark's file under ``data`` and its layout: the official file wins over the copy."""
    for name, layout in ((OFFICIAL, "official"), (SHIFTED, "shifted")):
        hits = sorted(glob.glob(os.path.join(data, "**", name), recursive=True))
        if hits:
            return hits[0], layout
    raise MissingInputError(f"neither {OFFICIAL} nor {SHIFTED} found under {data}: clone "
                            "https://github.com/yifang0-0/Physics-Guided-Recurrent-State-Space-Neural-Networks there, "
                            "or have the official loader download it (docs/guide/real-robots.md)")


def _cut(u: np.ndarray, y: np.ndarray, length: int) -> list:
    """Consecutive trajectories of ``length`` samples; a shorter last one is kept as it is."""
    return [(u[s:s + length], y[s:s + length]) for s in range(0, len(u), length) if len(u[s:s + length]) > 2]


def _trim_padding(u: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    # The copy pads its last validation trajectory with exact zero torques: no robot sample.
    n = len(u)
    while n > 0 and not np.any(u[n - 1]):
        n -= 1
    return u[:n], y[:n]


def load(data: str | None = None, path: str | None = None) -> IndustrialBenchmark:
    """Reads the benchmark from ``path``, or from the file :func:`find` picks under ``data``.

    Raises:
        MissingInputError: no file.
        IndustrialDataError: a file without the benchmark's variables.
    """
    if path is None:
        if data is None:
            raise IndustrialDataError("give the data folder or the benchmark's .mat file")
        path, _ = find(data)
    else:
        if not os.path.isfile(path):
            raise MissingInputError(f"{path} not found")
    from scipy.io import loadmat  # noqa: PLC0415

    try:
        m = loadmat(path)
    except (ValueError, OSError, NotImplementedError) as exc:
        raise IndustrialDataError(f"{path} is not a readable .mat file: {exc}") from None
    # The copy is told by its content, whatever the file is called: only it holds a validation part.
    layout = "shifted" if "u_val" in m else "official"
    need = ("u_train", "y_train", "u_test", "y_test") + (("y_val",) if layout == "shifted" else ())
    missing = [k for k in need if k not in m]
    if missing:
        raise IndustrialDataError(f"{path} lacks the benchmark's {', '.join(missing)}")

    def arr(key):
        a = np.asarray(m[key], np.float64)
        if a.ndim != 2 or a.shape[0] != 6:
            raise IndustrialDataError(f"{path}: {key} has shape {a.shape}, not (6, samples)")
        return a.T

    length = TRAJECTORY[layout]
    train = _cut(arr("u_train"), arr("y_train"), length)
    test = _cut(arr("u_test"), arr("y_test"), length)
    if layout == "shifted":
        val = [_trim_padding(u, y) for u, y in _cut(arr("u_val"), arr("y_val"), length)]
    else:  # the official file has no validation split: its last trajectories, cut by trajectory
        train, val = train[:-N_VAL], train[-N_VAL:]
    with open(path, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    return IndustrialBenchmark(path, layout, digest, train, val, test)
