"""The robots a hybrid's std is the spread of (``columns``, ``observed`` or ``draws``), and the calibrations that record
them."""

from __future__ import annotations


import numpy as np
import pytest
import torch

from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON
from tests.inference.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def _space(n: int):
    """What the spread moves: where the identified entries sit in a parameter vector, and their ranges."""
    return np.arange(n), -np.ones(n), np.ones(n)


def test_columns_are_the_linearized_propagation_of_the_covariance():
    """For a horizon linear in the parameters the columns' spread is exactly sqrt(diag(A' C A)); random draws
    only approach it, and draw by draw."""
    from robomorph.inference.hybrid_spread import draw_spread

    rng = np.random.default_rng(0)
    n, horizon, n_y = 5, 4, 3
    a = rng.standard_normal((n, horizon * n_y))
    root = 0.01 * rng.standard_normal((2, n, n))
    covs = [r @ r.T + 1e-4 * np.eye(n) for r in root]
    params = 0.1 * rng.standard_normal((2, n))  # far inside the ranges: nothing is clipped

    def linear(p):
        return (p @ a).reshape(len(p), horizon, n_y)

    mean = linear(params)
    cols = draw_spread(_space(n), params, None, covs, mean, linear, 8, 0, "columns")
    exact = np.stack([np.sqrt(np.einsum("ik,ij,jk->k", a, c, a)).reshape(horizon, n_y) for c in covs])
    np.testing.assert_allclose(cols, exact, rtol=1e-7)  # the factor's 1e-12 jitter
    draws = draw_spread(_space(n), params, None, covs, mean, linear, 8, 0, "draws")
    assert np.abs(np.log(draws / exact)).max() > 0.05  # eight draws miss it: the comparison can fail


def test_the_std_of_a_window_does_not_depend_on_its_batch(hybrid_ckpt, command_store):
    """A window's std is the same predicted alone or beside others (random draws were drawn per batch row)."""
    from robomorph.inference.predictor import Predictor

    uc, yc, uq, *_ = _windows(command_store, n=3)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    assert p.settings.points is None and p.hybrid().settings.points == "observed"  # not calibrated, with the observer
    for points in ("observed", "columns"):
        p.configure(points=points)
        _, alone = p.simulate(uc[2:], yc[2:], uq[2:], at_rest=True, return_std=True)
        _, batch = p.simulate(uc, yc, uq, at_rest=True, return_std=True)
        np.testing.assert_allclose(batch[2:], alone, rtol=1e-6)
    p.configure(points="draws")
    _, drawn = p.simulate(uc, yc, uq, at_rest=True, return_std=True)
    assert np.abs(drawn - batch).max() > 0  # the other spread, so the test above could fail


def test_the_observed_std_adds_the_start_velocitys_spread_to_the_columns(hybrid_ckpt, command_store):
    """``observed``: the columns' spread and, in quadrature, the horizons whose start velocity is moved joint by
    joint by the observer's correction there: larger than the columns' alone, most at the first steps (the state's
    error is most of theirs), and the columns' exactly without the observer (no correction to move by)."""
    from robomorph.inference.predictor import Predictor

    uc, yc, uq, *_ = _windows(command_store, n=2)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(members=1)
    std = {}
    for points in ("observed", "columns"):
        p.configure(points=points)
        std[points] = p.simulate(uc, yc, uq, at_rest=True, return_std=True)[1].astype(np.float64)
    joints = slice(7, 14)
    added = np.sqrt(np.maximum(std["observed"] ** 2 - std["columns"] ** 2, 0))[..., joints]
    assert np.all(std["observed"] >= std["columns"] * (1 - 1e-6))
    assert added[:, 0].max() > 0.1 * std["columns"][:, 0, joints].max()  # the term is not negligible at step 1
    share = added / std["observed"][..., joints]
    assert share[:, 0].mean() > share[:, -1].mean()  # the start's velocity matters most at the start
    p.configure(observer=False)
    for points in ("observed", "columns"):
        p.configure(points=points)
        std[points] = p.simulate(uc, yc, uq, at_rest=True, return_std=True)[1]
    np.testing.assert_array_equal(std["observed"], std["columns"])


def test_calibrations_record_their_points_and_old_ones_scale_the_draws(hybrid_ckpt, command_store, simulated_store,
                                                                     tmp_path, capsys):
    """calibrate records the points it fitted on (observed on a model never calibrated); a calibration without
    them (written before the choice) is applied to the random draws it was fitted on, exactly as before."""
    from robomorph.calibrate import main
    from robomorph.inference.calibration import CALIBRATION_KEY
    from robomorph.inference.hybrid import Hybrid
    from robomorph.inference.predictor import Predictor
    from robomorph.training.module import MetaModule

    out = str(tmp_path / "cal.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=8)
    assert main(["--ckpt", hybrid_ckpt, "--out", out, "--data", heldout, "--n", "4"]) == 0
    assert "std over one robot per column of the estimate's covariance and the observer's" in capsys.readouterr().out
    p = Predictor.from_checkpoint(out)
    assert p.calibration.points == "observed" and p.hybrid().settings.points == "observed"
    ckpt = torch.load(out, weights_only=False, map_location="cpu")
    del ckpt[CALIBRATION_KEY]["points"]  # as every calibration before the choice
    old_path = str(tmp_path / "old.ckpt")
    torch.save(ckpt, old_path)
    old = Predictor.from_checkpoint(old_path)
    assert old.calibration.points is None and old.hybrid().settings.points == "draws"
    uc, yc, uq, *_ = _windows(command_store, n=2)
    _, std = old.simulate(uc, yc, uq, at_rest=True, return_std=True)
    module = MetaModule.load_from_checkpoint(old_path, map_location="cpu").eval()
    hyb = Hybrid(module.trained_model, ckpt["robomorph_data"]["physics"], "command",
                 old.settings_in_effect.replace(points="draws"))
    _, raw = hyb.predict(*(torch.as_tensor(a, dtype=torch.float32) for a in (uc, yc, uq)), at_rest=True,
                         return_std=True)
    hyb.close()
    np.testing.assert_allclose(std, old.calibration.scaled(raw).astype(np.float32), rtol=1e-6)


def test_a_choice_other_than_the_calibrations_is_refused_in_one_line(hybrid_ckpt, command_store, simulated_store,
                                                                    tmp_path):
    """Asking a std of other points than the stored calibration's, or of an unknown name, is a CalibrationError
    that says what to do; a calibration of the other window kind on other points is refused the same way. A mean
    alone predicts as ever."""
    from robomorph.calibrate import main
    from robomorph.inference.calibration import CalibrationError
    from robomorph.inference.predictor import PredictionError
    from robomorph.inference.predictor import Predictor

    out = str(tmp_path / "cal.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON + 40, seed=9)  # room for random offsets
    assert main(["--ckpt", hybrid_ckpt, "--out", out, "--data", heldout, "--n", "4", "--points", "draws"]) == 0
    p = Predictor.from_checkpoint(out)
    assert p.calibration.points == "draws" and p.hybrid().settings.points == "draws"
    uc, yc, uq, *_ = _windows(command_store, n=2)
    p.configure(points="columns")
    with pytest.raises(CalibrationError, match="--points columns"):
        p.simulate(uc, yc, uq, at_rest=True, return_std=True)
    with pytest.raises(PredictionError, match="points 'sigma': choose one of"):  # refused where it is set
        p.configure(points="sigma")
    assert main(["--ckpt", out, "--data", heldout, "--n", "4", "--points", "columns", "--offset", "random"]) == 0
    mixed = Predictor.from_checkpoint(out)
    with pytest.raises(CalibrationError, match="different spreads"):
        mixed.simulate(uc, yc, uq, at_rest=True, return_std=True)
    # A prediction without a std needs no points: it is the same as the model's before the calibrations.
    np.testing.assert_array_equal(mixed.simulate(uc, yc, uq, at_rest=True),
                                  Predictor.from_checkpoint(hybrid_ckpt).simulate(uc, yc, uq, at_rest=True))


def test_calibration_points_round_trip_and_unknown_ones_are_refused():
    from robomorph.inference.calibration import CalibrationError, StdCalibration

    cal = StdCalibration((1, 2), ((1.0, 2.0), (1.5, 2.5)), "nll", {}, points="columns")
    assert StdCalibration.from_dict(cal.to_dict()) == cal
    doc = cal.to_dict()
    del doc["points"]
    assert StdCalibration.from_dict(doc).points is None
    with pytest.raises(CalibrationError, match="unknown spread points"):
        StdCalibration.from_dict({**cal.to_dict(), "points": "sigma"})
