"""Every physics mode's predictions, mean and std, what they were when the fixtures were written
(``python -m tests.inference.kept_predictions``): a reorganization of the code moves no number beyond rounding.

Compared with a stated tolerance, not bit for bit: float32 network parts and BLAS kernels differ in their last bits
between CPUs (a fresh Intel Xeon moved the means by about 6e-8 relative). The tolerances, relative to each array's
largest magnitude: means 1e-5, stds 1e-3. The std's is wider because the spread amplifies rounding of the identified
parameters (about 100x the mean's, measured by the one-ulp test below); the jumps it replaces (a most likely friction
member chosen by argmax, a smoother covariance carrying its step's damping) moved stds by 0.3 to 33 %."""

from __future__ import annotations

import numpy as np
import pytest

from tests.inference.kept_predictions import KEPT, predictions

MEAN_RTOL, STD_RTOL = 1e-5, 1e-3


def _moved(got: dict, kept, key: str) -> float:
    """The largest change of ``key`` relative to the kept array's largest magnitude."""
    ref = np.asarray(kept[key], dtype=np.float64)
    return float(np.abs(np.asarray(got[key], dtype=np.float64) - ref).max() / max(np.abs(ref).max(), 1e-300))


def _tolerance(key: str) -> float:
    return STD_RTOL if key.endswith("/std") else MEAN_RTOL


@pytest.fixture(scope="module")
def got():
    return predictions()


def test_every_mode_predicts_what_it_predicted_when_the_fixtures_were_written(got):
    kept = np.load(KEPT / "predictions.npz")
    assert sorted(got) == sorted(kept.files)
    moved = {k: _moved(got, kept, k) for k in kept.files}
    changed = {k: f"{r:.3g}" for k, r in moved.items() if not r <= _tolerance(k)}
    assert not changed, f"predictions moved beyond rounding (means {MEAN_RTOL}, stds {STD_RTOL}): {changed}"


def test_the_kept_cases_differ_from_each_other_so_the_check_can_fail():
    kept = np.load(KEPT / "predictions.npz")
    pairs = [("command/regression/moving/mean", "command/members=1/moving/mean"),
             ("command/regression/moving/mean", "command/learned/moving/mean"),
             ("total_smoothed/smoothed/rest/mean", "total_smoothed/none/rest/mean"),
             ("command/points=draws/moving/std", "command/points=draws,samples=4/moving/std")]
    for a, b in pairs:  # apart by far more than the tolerance, so a swap of modes would be caught
        assert _moved({a: kept[b]}, kept, a) > 100 * _tolerance(a), (a, b)


# A one-ulp change of one context sample's joint angles moves every mean by less than ONE_ULP_MEAN and every std by
# less than ONE_ULP_STD of its largest magnitude (measured at most 1.2e-4 and 4.2e-3). Before the fixes the std moved
# by up to 33 % (the smoother), 10 % (fused, the friction members' argmax), 3.6 % (regression at rest).
ONE_ULP_MEAN, ONE_ULP_STD = 1e-3, 1e-2


def test_a_one_ulp_change_of_the_context_moves_no_mean_or_std_by_a_jump(got, tmp_path):
    windows = dict(np.load(KEPT / "windows.npz"))
    for name in ("command_y", "total_y"):  # the first context sample's joints, one float32 ulp up
        joints = windows[name][:, 0, 7:14].copy()
        windows[name][:, 0, 7:14] = np.nextafter(joints, np.float32(np.inf))
        assert windows[name].dtype == np.float32 and not np.array_equal(windows[name][:, 0, 7:14], joints)
    for item in KEPT.iterdir():
        if item.name != "windows.npz":
            (tmp_path / item.name).symlink_to(item)
    np.savez(tmp_path / "windows.npz", **windows)
    nudged = predictions(tmp_path)
    limits = {k: ONE_ULP_STD if k.endswith("/std") else ONE_ULP_MEAN for k in got}
    moved = {k: _moved(nudged, got, k) for k in got}
    jumped = {k: f"{r:.3g}" for k, r in moved.items() if not r < limits[k]}
    assert not jumped, f"a one-ulp change of the context moved these by a jump: {jumped}"
    assert max(moved.values()) > 0, "the nudge reached no prediction: the test would pass on anything"
