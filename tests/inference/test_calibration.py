"""The per-horizon std calibration: knots, fitting, interpolation, storage, application."""

import numpy as np
import pytest
import torch

from robomorph.inference.calibration import (ONE_SIGMA, POWER_MIN_WINDOWS, TWO_SIGMA, CalibrationError, StdCalibration,
                                        fit, knot_steps, read_calibrations, calibrations_entry, step_bands)
from robomorph.inference.checkpoint import TrainedModel
from robomorph.model.transformer import ModelConfig


def test_knots_are_log_spaced_distinct_steps_from_one_to_the_horizon():
    for h in (1, 2, 7, 60, 800):
        k = knot_steps(h)
        assert k[0] == 1 and k[-1] == h and (np.diff(k) > 0).all()
    k = knot_steps(800)
    ratios = k[1:] / k[:-1]
    assert len(k) >= 10 and ratios[-3:].max() < 1.6  # dense at long horizons too
    with pytest.raises(CalibrationError, match=">= 1"):
        knot_steps(0)


def test_the_bands_tile_every_step_once():
    k = knot_steps(800)
    bands = step_bands(k, 800)
    assert sorted(np.concatenate(bands).tolist()) == list(range(800))
    assert all(k[i] - 1 in b for i, b in enumerate(bands))  # each knot lies in its own band


def _synthetic(n=400, h=100, c=3, seed=0):
    """Windows whose true spread is the predicted std times a factor growing with the step."""
    rng = np.random.default_rng(seed)
    mean = rng.normal(size=(n, h, c))
    std = np.exp(rng.normal(size=(n, h, c)) * 0.3)
    true_factor = (1 + np.arange(1, h + 1) / 20.0)[None, :, None] * np.array([1.0, 2.0, 0.5])
    y = mean + std * true_factor * rng.normal(size=(n, h, c))
    return y, mean, std, true_factor[0]


def test_nll_scales_recover_the_true_spread_and_calibrate_coverage():
    y, mean, std, true = _synthetic()
    cal = fit(y, mean, std, "nll")
    f = cal.factors(100)
    assert f.shape == (100, 3)
    np.testing.assert_allclose(f[np.asarray(cal.knots) - 1], true[np.asarray(cal.knots) - 1], rtol=0.15)
    z = np.abs(y - mean) / (std * f[None])
    raw = np.abs(y - mean) / std
    assert abs((z <= 1).mean() - ONE_SIGMA) < 0.02 and abs((z <= 2).mean() - 0.954) < 0.02
    assert abs((raw <= 1).mean() - ONE_SIGMA) > 0.1  # it was miscalibrated before


def test_quantile_scales_put_68_percent_inside_one_sigma_in_every_band():
    y, mean, std, _ = _synthetic(seed=1)
    cal = fit(y, mean, std, "quantile")
    z = np.abs(y - mean) / std
    for i, band in enumerate(step_bands(np.asarray(cal.knots), 100)):
        inside = (z[:, band] <= np.asarray(cal.scale[i])).reshape(-1, 3).mean(0)
        np.testing.assert_allclose(inside, ONE_SIGMA, atol=0.01)


def test_coverage_scales_meet_both_levels_on_heavy_tailed_errors_where_one_level_methods_miss_one():
    rng = np.random.default_rng(3)
    shape = (400, 50, 2)
    y = rng.standard_t(5, size=shape)  # heavy tails: no single scale makes them Gaussian
    mean, std = np.zeros(shape), np.full(shape, 0.5)

    def coverage(cal):
        z = np.abs(y) / (std * cal.factors(shape[1])[None])
        return np.mean(z <= 1), np.mean(z <= 2)

    one, two = coverage(fit(y, mean, std, "coverage"))
    assert abs(one - ONE_SIGMA) < 0.05 and abs(two - TWO_SIGMA) < 0.03
    nll_one, _ = coverage(fit(y, mean, std, "nll"))
    _, q_two = coverage(fit(y, mean, std, "quantile"))
    assert nll_one - ONE_SIGMA > 0.05 and TWO_SIGMA - q_two > 0.02  # each one-level method strays further
    gauss = rng.normal(0, 2.0, size=shape)  # Gaussian errors: every method finds the true scale (4x the std)
    for method in ("nll", "quantile", "coverage"):
        scale = np.asarray(fit(gauss, mean, std, method).scale)
        assert abs(np.median(scale) - 4.0) < 0.2 and np.allclose(scale, 4.0, rtol=0.2)  # few samples at step 1


def _over_spread(n: int, seed: int = 5):
    """Errors whose true spread is the square root of the predicted one (in its units): the
    prediction's spread varies too much across windows, so its z has heavy tails."""
    rng = np.random.default_rng(seed)
    shape = (n, 30, 2)
    std = np.exp(rng.normal(0.0, 1.5, size=(n, 1, 2))) * np.ones(shape)  # one spread per window and channel
    y = rng.normal(size=shape) * 3.0 * np.sqrt(std)
    return y, np.zeros(shape), std


def _levels(y, mean, std_cal):
    z = np.abs(y - mean) / std_cal
    return float(np.mean(z <= 1)), float(np.mean(z <= 2))


def test_a_power_of_the_spread_meets_both_levels_where_one_scale_cannot():
    y, mean, std = _over_spread(400)
    power = fit(y, mean, std, "power")
    p = np.asarray(power.power)
    assert np.median(p) == 0.5 and p.min() >= 0.25 and p.max() <= 0.75  # the spread's true power, knot by knot
    one, two = _levels(y, mean, power.scaled(std))
    assert abs(one - ONE_SIGMA) < 0.03 and abs(two - TWO_SIGMA) < 0.015
    scale = fit(y, mean, std, "coverage")
    one, two = _levels(y, mean, scale.scaled(std))
    assert max(abs(one - ONE_SIGMA) / 0.05, abs(two - TWO_SIGMA) / 0.03) > 1  # one scale misses a band
    # Fresh windows of the same kind: the fitted power holds out of sample.
    y2, mean2, std2 = _over_spread(400, seed=6)
    one, two = _levels(y2, mean2, power.scaled(std2))
    assert abs(one - ONE_SIGMA) < 0.05 and abs(two - TWO_SIGMA) < 0.03


def test_with_few_windows_the_power_stays_one_and_the_scales_are_coverages():
    y, mean, std = _over_spread(POWER_MIN_WINDOWS - 1)
    power, scale = fit(y, mean, std, "power"), fit(y, mean, std, "coverage")
    assert np.all(np.asarray(power.power) == 1.0) and np.allclose(power.scale, scale.scale, rtol=1e-12)
    np.testing.assert_allclose(power.scaled(std), scale.scaled(std))


def test_a_power_calibration_round_trips_through_a_model_file_and_applies_alike_in_numpy_and_torch():
    y, mean, std = _over_spread(200)
    cal = fit(y, mean, std, "power", source={"physics_mode": "regression"})
    assert StdCalibration.from_dict(cal.to_dict()) == cal
    assert read_calibrations(calibrations_entry({"regression": cal}))["regression"] == cal
    np.testing.assert_allclose(cal.apply(torch.as_tensor(std)).numpy(), cal.scaled(std), rtol=1e-12)
    plain = StdCalibration(cal.knots, cal.scale)  # without a power: the factors alone
    np.testing.assert_allclose(plain.scaled(std), std * plain.factors(std.shape[1])[None])
    doc = cal.to_dict()
    with pytest.raises(CalibrationError, match="together"):
        StdCalibration.from_dict({**doc, "reference": None})
    with pytest.raises(CalibrationError, match="positive"):
        StdCalibration.from_dict({**doc, "reference": [[-1.0] * 2] * len(doc["knots"])})


def test_factors_equal_the_scales_at_knots_interpolate_log_log_and_hold_outside():
    cal = StdCalibration((1, 4, 16), ((1.0, 2.0), (2.0, 2.0), (8.0, 1.0)))
    f = cal.factors(400)
    np.testing.assert_allclose(f[[0, 3, 15]], [[1, 2], [2, 2], [8, 1]])
    np.testing.assert_allclose(f[8 - 1, 0], 4.0)  # step 8, halfway from 4 to 16 in log step: sqrt(2 * 8)
    np.testing.assert_allclose(f[399], [8.0, 1.0])  # flat beyond the last knot
    assert cal.factors(5).shape == (5, 2)


def test_a_calibration_round_trips_and_bad_ones_are_refused():
    cal = StdCalibration((1, 5), ((1.5, 0.5), (2.0, 1.0)), "quantile", {"split": "val", "n": 12})
    assert StdCalibration.from_dict(cal.to_dict()) == cal
    for bad in ({"knots": [5, 1], "scale": [[1.0], [1.0]]}, {"knots": [1, 2], "scale": [[1.0], [-1.0]]},
                {"knots": [1, 2], "scale": [[1.0]]}, {"knots": [1], "scale": [[float("nan")]]},
                {"scale": [[1.0]]}, {"knots": [1], "scale": [[1.0]], "method": "isotonic"}):
        with pytest.raises(CalibrationError):
            StdCalibration.from_dict(bad)
    with pytest.raises(CalibrationError, match="same shape|one shape"):
        fit(np.zeros((4, 5, 2)), np.zeros((4, 5, 2)), np.ones((4, 6, 2)))
    with pytest.raises(CalibrationError, match="at least 2"):
        fit(np.zeros((1, 5, 2)), np.zeros((1, 5, 2)), np.ones((1, 5, 2)))


def _model(gaussian: bool) -> TrainedModel:
    torch.manual_seed(0)
    m = TrainedModel(ModelConfig(n_u=2, n_y=3, d_model=16, n_head=2, n_layer=1, patch=5, max_context=40,
                                 max_horizon=40, gaussian=gaussian)).eval()
    return m


def test_the_model_scales_its_std_and_leaves_the_mean_alone():
    m = _model(True)
    u_ctx, y_ctx, u_q = torch.randn(2, 20, 2), torch.randn(2, 20, 3), torch.randn(2, 30, 2)
    with torch.no_grad():
        mean0, std0 = m.forward_dist(u_ctx, y_ctx, u_q)
        cal = StdCalibration((1, 10, 30), ((2.0, 1.0, 0.5), (3.0, 1.0, 0.5), (4.0, 1.0, 0.5)))
        m.set_calibration(cal)
        mean1, std1 = m.forward_dist(u_ctx, y_ctx, u_q)
        _, raw = m.forward_dist_raw(u_ctx, y_ctx, u_q)
    assert torch.equal(mean0, mean1) and torch.equal(raw, std0)
    torch.testing.assert_close(std1, std0 * torch.as_tensor(cal.factors(30), dtype=std0.dtype))
    with pytest.raises(CalibrationError, match="channels"):
        m.set_calibration(StdCalibration((1,), ((1.0, 1.0),)))
    with pytest.raises(CalibrationError, match="no Gaussian head"):
        _model(False).set_calibration(cal)


def test_end_dense_knots_mirror_the_first_half_onto_the_second():
    from robomorph.inference.calibration import end_dense_knots

    knots = end_dense_knots(800)
    head = knot_steps(800)[knot_steps(800) <= 400]
    assert knots[0] == 1 and knots[-1] == 800 and (np.diff(knots) > 0).all()
    assert list(knots[:len(head)]) == list(head) and list(knots[len(head):]) == list(801 - head[::-1])
    assert list(end_dense_knots(3)) == list(knot_steps(3))  # too short to split: the plain knots


def _end_heavy_errors(horizon, n=400, seed=0):
    """Windows whose error spread quadruples over the last 50 steps of their horizon (a smoother's
    end, with no later torque to pin it) while the predicted spread stays flat."""
    rng = np.random.default_rng(seed)
    to_end = horizon - np.arange(1, horizon + 1)
    spread = 1.0 + 3.0 * np.exp(-to_end / 25.0)
    err = rng.normal(size=(n, horizon, 2)) * spread[None, :, None]
    return err, np.zeros_like(err), np.ones_like(err)


def _inside(y, mean, std, cal, step, k):
    """The share of the windows' values at 1-based ``step`` inside ±k of ``cal``'s calibrated std."""
    return float(np.mean(np.abs(y - mean)[:, step - 1] < k * cal.scaled(std)[:, step - 1]))


def test_end_dense_knots_follow_errors_that_grow_toward_the_horizons_end():
    y, mean, std = _end_heavy_errors(800)
    plain, dense = fit(y, mean, std, "coverage"), fit(y, mean, std, "coverage", end=True)

    # the plain knots' last band pools the last step with many earlier ones of smaller error
    assert _inside(y, mean, std, plain, 800, 2) < TWO_SIGMA - 0.03
    assert abs(_inside(y, mean, std, dense, 800, 2) - TWO_SIGMA) < 0.03
    assert abs(_inside(y, mean, std, dense, 800, 1) - ONE_SIGMA) < 0.05
    assert abs(_inside(y, mean, std, dense, 400, 2) - TWO_SIGMA) < 0.03  # mid-horizon as before
    back = StdCalibration.from_dict(dense.to_dict())  # its knots are stored: it applies as any other
    np.testing.assert_allclose(back.scaled(std[:, :500]), dense.scaled(std[:, :500]))
    with pytest.raises(CalibrationError, match="pass knots or end, not both"):
        fit(y, mean, std, "coverage", knots=np.array([1, 10, 800]), end=True)


def test_calibrate_places_end_dense_knots_for_every_hybrid_prediction_only():
    from types import SimpleNamespace

    from robomorph.evaluation.calibrating import dense_at_end
    from robomorph.inference.hybrid import MODES

    def predictor(mode, physics=True):
        return SimpleNamespace(physics={"x": 1} if physics else None, physics_mode=mode)

    assert all(dense_at_end(predictor(mode)) for mode in MODES)  # smoothed or simulated forward alike
    assert not dense_at_end(predictor("none", physics=False))  # the black-box decoder keeps log-spaced knots


def test_end_dense_knots_follow_errors_that_keep_growing_to_the_horizons_end():
    """A forward simulation's errors grow along the whole horizon: log-spaced knots fit the last one on the
    band to its left and hold it flat, which leaves the last step short at +-2 sigma."""
    rng = np.random.default_rng(3)
    horizon = 600
    err = rng.standard_t(5, size=(2000, horizon, 1)) * np.arange(1, horizon + 1)[None, :, None] ** 1.5
    y, mean, std = err, np.zeros_like(err), np.ones_like(err)
    plain, dense = fit(y, mean, std, "power"), fit(y, mean, std, "power", end=True)

    assert _inside(y, mean, std, plain, horizon, 2) < TWO_SIGMA - 0.03  # outside the goal band
    assert abs(_inside(y, mean, std, dense, horizon, 2) - TWO_SIGMA) < 0.03
    assert abs(_inside(y, mean, std, dense, horizon, 1) - ONE_SIGMA) < 0.05


def test_outside_bands_names_the_steps_that_leave_68_plus_minus_5_or_95_plus_minus_3():
    from robomorph.inference.calibration import outside_bands

    assert outside_bands([0.68, 0.74, 0.70, 0.62], [0.95, 0.95, 0.915, 0.95]) == [1, 2, 3]
    assert outside_bands([0.73, 0.64], [0.93, 0.98]) == []
