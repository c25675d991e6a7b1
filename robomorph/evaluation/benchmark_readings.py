"""The industrial robot benchmark's readings: one predictor, the four ways its figures are read.

Published figures on this benchmark are not one measurement (docs/guide/real-robots.md):

- (a) ``paper``: the paper as written (Fañanás-Anaya et al. 2024, Eq. 23-24): the whole test set
  as one sequence, free-run from its first sample; NRMSE = sqrt(mean over joints of
  (RMSE_j / std_j)^2), std over the test outputs;
- (b) ``per_trajectory``: each test trajectory free-run from its own first sample (at rest), the
  errors pooled, the same Eq. 23 (std over the test outputs);
- (c) ``range``: the same per-trajectory runs; RMSE of each trajectory and joint divided by that
  trajectory's range (max - min) of the joint, the arithmetic mean over both (the authors' public
  code and its README);
- (d) identibench's ``BenchmarkRobotForward_Simulation`` (the test as one sequence, 100 samples of
  warm-up, the rest free-run; RMSE [deg] per joint, the joints' mean) and
  ``BenchmarkRobotForward_Prediction`` (windows of 100 warm-up + 100 predicted samples every
  100; RMSE over the whole window, warm-up included as identibench scores it, the mean over
  windows and joints). :func:`identibench_readings` runs identibench's own tasks where it is
  installed; :func:`simulation_rmse` and :func:`prediction_rmse` are the same arithmetic.

A predictor is ``predict(u, y_init) -> y_hat``: ``u`` (T, n_u) the whole input, ``y_init`` (w, n_y)
the true outputs of the warm-up, ``y_hat`` (T, n_y) with ``y_hat[:w] = y_init``. Nothing here
hands it a true output after the warm-up.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable

import numpy as np

Predict = Callable[[np.ndarray, np.ndarray], np.ndarray]
READINGS = ("paper", "per_trajectory", "range", "identibench_simulation", "identibench_prediction")
IDENTIBENCH_INIT, IDENTIBENCH_HORIZON = 100, 100


def free_run(predict: Predict, u: np.ndarray, y: np.ndarray, warmup: int) -> np.ndarray:
    """``predict`` on ``u`` from the first ``warmup`` true outputs of ``y`` alone (a copy: the
    predictor cannot reach the rest); the prediction (T, n_y), checked for shape."""
    y_init = np.array(y[:warmup], dtype=np.float64, copy=True)
    out = np.asarray(predict(np.array(u, dtype=np.float64, copy=True), y_init), dtype=np.float64)
    if out.shape != y.shape:
        raise ValueError(f"a predictor returned {out.shape} for outputs of shape {y.shape}")
    return out


def nrmse_eq23(err: np.ndarray, y_ref: np.ndarray) -> float:
    """Eq. 23-24: sqrt(mean_j (RMSE_j / std_j)^2); ``err`` (N, n_y) the scored errors, the std of
    each joint over ``y_ref`` (the test outputs)."""
    rmse = np.sqrt(np.mean(err ** 2, axis=0))
    return float(np.sqrt(np.mean((rmse / np.std(y_ref, axis=0)) ** 2)))


def nrmse_range(y_true: list, y_pred: list) -> float:
    """The public code's metric: RMSE / (max - min) per trajectory and joint, then the mean."""
    vals = [np.sqrt(np.mean((p - t) ** 2, axis=0)) / (t.max(0) - t.min(0)) for t, p in zip(y_true, y_pred)]
    return float(np.mean(vals))


def simulation_rmse(predict: Predict, u: np.ndarray, y: np.ndarray, init: int = IDENTIBENCH_INIT) -> float:
    """identibench's Simulation task: the sequence free-run after ``init`` samples, RMSE per joint
    over the rest, the joints' mean."""
    pred = free_run(predict, u, y, init)
    return float(np.mean(np.sqrt(np.mean((pred[init:] - y[init:]) ** 2, axis=0))))


def prediction_rmse(predict: Predict, u: np.ndarray, y: np.ndarray, init: int = IDENTIBENCH_INIT,
                    horizon: int = IDENTIBENCH_HORIZON, step: int = IDENTIBENCH_HORIZON) -> float:
    """identibench's Prediction task: windows of ``init + horizon`` samples every ``step``, each
    from its own ``init`` true outputs; RMSE per joint over the whole window, the mean over
    windows and joints."""
    win = init + horizon
    if len(u) < win:
        raise ValueError(f"a sequence of {len(u)} samples is shorter than one window of {init} + {horizon}")
    scores = []
    for s in range(0, len(u) - win + 1, step):
        pred = free_run(predict, u[s:s + win], y[s:s + win], init)
        scores.append(np.sqrt(np.mean((pred - y[s:s + win]) ** 2, axis=0)))
    return float(np.mean(scores))


def readings(predict: Predict, test: list, warmup: int = 1, identibench: bool = True) -> dict[str, float]:
    """Every reading of one predictor on the test trajectories ``[(u, y), ...]``.

    ``warmup`` true samples start each free run of readings (a)-(c) (1: from the first sample,
    as the paper states). ``identibench``: score (d) through the installed identibench, else
    (or when it is not installed) through this module's arithmetic; NaN where the test is shorter
    than one of its windows.
    """
    u_all = np.concatenate([u for u, _ in test])
    y_all = np.concatenate([y for _, y in test])
    pred_all = free_run(predict, u_all, y_all, warmup)
    preds = [free_run(predict, u, y, warmup) for u, y in test]
    err_b = np.concatenate([p[warmup:] - y[warmup:] for p, (_, y) in zip(preds, test)])
    out = {"paper": nrmse_eq23(pred_all[warmup:] - y_all[warmup:], y_all),
           "per_trajectory": nrmse_eq23(err_b, y_all),
           "range": nrmse_range([y[warmup:] for _, y in test], [p[warmup:] for p in preds])}
    if len(u_all) < IDENTIBENCH_INIT + IDENTIBENCH_HORIZON:  # too short for identibench's specs
        spec = {"identibench_simulation": float("nan"), "identibench_prediction": float("nan")}
    elif identibench and identibench_installed():
        spec = identibench_readings(predict, u_all, y_all)
    else:
        spec = {"identibench_simulation": simulation_rmse(predict, u_all, y_all),
                "identibench_prediction": prediction_rmse(predict, u_all, y_all)}
    out.update(spec)
    return out


def identibench_installed() -> bool:
    try:
        import identibench  # noqa: F401, PLC0415
    except ImportError:
        return False
    return True


def identibench_readings(predict: Predict, u: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """(d) through identibench's own RobotForward tasks: the test sequence written as its test file
    (``robot_forward/test/test.hdf5`` under a temporary data root, as its preparer writes it from the
    .mat) and each spec's task run on it; nothing is downloaded."""
    import h5py  # noqa: PLC0415
    import identibench.utils as ib_utils  # noqa: PLC0415
    from identibench.datasets.industrial_robot import (  # noqa: PLC0415
        BenchmarkRobotForward_Prediction, BenchmarkRobotForward_Simulation, robot_forward_dataset)

    def model(u_seq, y_init, attrs):  # identibench's model contract: (u, y_init, attrs) -> (T, n_y)
        return predict(np.asarray(u_seq, np.float64), np.asarray(y_init, np.float64))

    with tempfile.TemporaryDirectory() as root, ib_utils.data_root(root):
        folder = os.path.join(robot_forward_dataset.path, "test")
        os.makedirs(folder)
        with h5py.File(os.path.join(folder, "test.hdf5"), "w") as f:
            ib_utils.write_array(f, "u", u)
            ib_utils.write_array(f, "y", y)
            f.attrs["fs"] = 10
        out = {}
        for key, spec in (("identibench_simulation", BenchmarkRobotForward_Simulation),
                          ("identibench_prediction", BenchmarkRobotForward_Prediction)):
            result = spec.task(spec, model)
            out[key] = float(result.scores[result.headline[0]][result.headline[1]])
    return out
