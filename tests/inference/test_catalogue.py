"""A prediction with no training: Predictor.from_arm is the trained command hybrid's regression, with no network."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph import Predictor
from robomorph.inference.catalogue import NoNetworkError
from tests.conftest import CKPT_CONTEXT as C
from tests.conftest import CKPT_HORIZON as H
from tests.conftest import tiny_fit_args


@pytest.fixture(scope="module")
def store(simulated_store):
    return simulated_store(robots=24, steps=C + H, seed=3)


def _windows(store: str, n: int = 3):
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y = ds.read_inputs("command")[:n], ds.read("y")[:n]
    return u[:, :C], y[:, :C], u[:, C:], y[:, C:], dict(ds.attrs)


def test_it_predicts_what_a_trained_command_hybrid_predicts_to_the_bit(store, tmp_path):
    from robomorph.training.fitting import fit

    ckpt = fit(tiny_fit_args(store, tmp_path / "runs", "hybrid", steps=2, data={"inputs": "command"},
                             model={"physics": "amortized", "anchor": True})).best_ckpt
    trained = Predictor.from_checkpoint(ckpt, device="cpu")
    uc, yc, uq, _, attrs = _windows(store)
    arm = Predictor.from_arm("panda", **attrs["config"])  # the recipe the store was generated with
    assert (arm.settings.mode, arm.inputs) == (trained.settings.mode, trained.inputs) == ("regression", "command")
    want = trained.simulate(uc, yc, uq, return_std=True, at_rest=True)
    got = arm.simulate(uc, yc, uq, return_std=True, at_rest=True)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])
    assert arm.calibration is None and trained.calibration is None  # neither was calibrated


def test_with_the_generators_defaults_it_follows_the_recorded_robot_far_better_than_hold(store):
    uc, yc, uq, yq, _ = _windows(store)
    pred = Predictor.from_arm("panda")  # nothing from the store: the arm and the generator's default recipe
    mean, std = pred.simulate(uc, yc, uq, return_std=True, at_rest=True)
    assert mean.shape == std.shape == yq.shape and np.all(np.isfinite(mean)) and np.all(std > 0)
    joints = slice(7, 14)
    err = np.sqrt(np.mean((mean[..., joints] - yq[..., joints]) ** 2))
    hold = np.sqrt(np.mean((yc[:, -1:, joints] - yq[..., joints]) ** 2))
    assert err < 0.05 * hold, (err, hold)
    one = pred.simulate(uc[0], yc[0], uq[0], at_rest=True)  # one window: (T, n_y) in and out
    np.testing.assert_array_equal(one, mean[0])


def test_what_needs_a_network_is_refused_in_one_line(store):
    uc, yc, uq, _, _ = _windows(store, n=1)
    pred = Predictor.from_arm("panda")
    for mode in ("none", "blend", "smoothed", "learned", "fused"):  # the decoder's and the parameter head's
        pred.use_physics(mode)
        with pytest.raises(NoNetworkError, match=rf"^physics mode '{mode}' reads a trained network") as exc:
            pred.simulate(uc, yc, uq)  # refused before anything runs
        assert "\n" not in str(exc.value)
    pred.use_physics("refined")  # reads no network either
    assert pred.simulate(uc, yc, uq).shape == uq.shape[:2] + (14,)
    with pytest.raises(NoNetworkError, match=r"unknown arm 'ur6'.*choose one of panda, ur5e"):
        Predictor.from_arm("ur6")
