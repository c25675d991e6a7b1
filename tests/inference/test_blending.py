"""The physics/decoder blend by horizon (robomorph.inference.blending) and its fitting (calibrate --blend)."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph.inference.blending import BlendError, HorizonBlend, fit_blend
from robomorph.inference.calibration import step_bands
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON


def _two_sources(seed: int = 0, n: int = 40, horizon: int = 100, n_y: int = 3):
    """Truth, a physics prediction whose error grows tenfold every 20 steps from 1e-3, and a
    decoder whose error is 0.1 at every step."""
    rng = np.random.default_rng(seed)
    y = rng.normal(size=(n, horizon, n_y))
    growth = 1e-3 * 10 ** (np.arange(horizon) / 20.0)
    physics = y + growth[None, :, None] * rng.normal(size=y.shape)
    decoder = y + 0.1 * rng.normal(size=y.shape)
    return y, physics, decoder


def test_the_weights_follow_which_source_is_better_and_the_blend_beats_both_in_every_band():
    y, physics, decoder = _two_sources()
    blend = fit_blend(y, physics, decoder)
    w = blend.weights(100)
    assert w.shape == (100, 3)
    assert np.all(w[:10] > 0.95) and np.all(w[-10:] < 0.05)  # physics early, the decoder late
    mixed = blend.combine(physics, decoder)[0]
    for band in step_bands(np.asarray(blend.knots), 100):
        err = {k: np.mean((v[:, band] - y[:, band]) ** 2) for k, v in
               (("blend", mixed), ("physics", physics), ("decoder", decoder))}
        # Interpolating the knots' weights inside a band is not the band's own optimum: within 5 %.
        assert err["blend"] <= 1.05 * min(err["physics"], err["decoder"])


def test_a_diverged_simulation_falls_back_to_the_decoder_and_leaves_the_fit_finite():
    y, physics, decoder = _two_sources(1)
    physics[3, 40:] = np.nan
    physics[5, 70:] = np.inf
    blend = fit_blend(y, physics, decoder)
    assert np.all(np.isfinite(np.asarray(blend.weight)))
    mixed, std = blend.combine(physics, decoder, np.full(y.shape, 0.01), np.full(y.shape, 0.1))
    assert np.all(np.isfinite(mixed)) and np.all(np.isfinite(std))
    np.testing.assert_array_equal(mixed[3, 40:], decoder[3, 40:])
    np.testing.assert_allclose(std[3, 40:], 0.1)


def test_a_window_whose_physics_leaves_is_the_decoders_from_there_on_and_the_gate_is_fitted():
    y, physics, decoder = _two_sources(2, horizon=60)
    physics[:, 40:] = decoder[:, 40:]  # no window's physics diverges on its own here
    physics[4, 12:20] += 5.0  # one simulation leaves the trajectory at step 13 (and comes back at 21)
    blend = fit_blend(y, physics, decoder)
    assert np.isfinite(blend.gate)  # the gate pays off here
    gated = blend.gated(physics, decoder)
    assert gated[4, 12:].all() and not gated[4, :12].any()  # from step 13 on, for good
    assert not gated[np.arange(len(y)) != 4].any()
    mixed = blend.combine(physics, decoder)[0]
    np.testing.assert_array_equal(mixed[4, 12:], decoder[4, 12:])
    ungated = HorizonBlend(blend.knots, blend.weight, decoder_rms=blend.decoder_rms)  # gate inf: never
    assert np.mean((ungated.combine(physics, decoder)[0] - y) ** 2) > np.mean((mixed - y) ** 2)


def test_the_gate_is_continuous_a_departure_just_past_it_moves_the_blend_a_little():
    """A physics that departs from its decoder by just under the gate, then by just over it: the blend moves by about
    as much as the physics did, where a cut at the gate handed the rest of the horizon to the decoder (issue 61)."""
    from robomorph.inference.blending import GATE_RAMP

    blend = HorizonBlend((1, 10), ((1.0,), (1.0,)), decoder_rms=((0.1,), (0.1,)), gate=3.0)
    decoder = np.zeros((1, 10, 1))
    limit = blend.gate * 0.1  # the departure at the gate
    inside, past = (np.where(np.arange(10)[None, :, None] >= 4, limit * f, 0.0) for f in (0.99, 1.01))
    moved = np.abs(blend.combine(past, decoder)[0] - blend.combine(inside, decoder)[0]).max()
    assert moved < 0.05 * limit, moved  # 0.02 of it here; the cut moved it by 0.99 of it
    np.testing.assert_array_equal(blend.combine(inside, decoder)[0], inside)  # below the gate: the physics whole
    np.testing.assert_array_equal(blend.kept(inside, decoder), 1.0)
    far = np.where(np.arange(10)[None, :, None] == 4, GATE_RAMP * limit, 0.0)  # past the ramp once: gone for good
    np.testing.assert_array_equal(blend.kept(far, decoder)[0], [1, 1, 1, 1, 0, 0, 0, 0, 0, 0])
    half = np.where(np.arange(10)[None, :, None] >= 4, (1 + GATE_RAMP) / 2 * limit, 0.0)
    np.testing.assert_allclose(blend.combine(half, decoder)[0][0, 4:], 0.5 * half[0, 4:], rtol=1e-12)


def test_the_blends_std_is_that_of_independent_errors():
    blend = HorizonBlend((1, 10), ((0.25,), (0.25,)))
    p, d = np.zeros((1, 10, 1)), np.ones((1, 10, 1))
    mean, std = blend.combine(p, d, np.full(p.shape, 2.0), np.full(p.shape, 1.0))
    np.testing.assert_allclose(mean, 0.75)
    np.testing.assert_allclose(std, np.sqrt((0.25 * 2) ** 2 + (0.75 * 1) ** 2))


def test_round_trip_and_refusals():
    blend = HorizonBlend((1, 5, 30), ((1.0, 0.9), (0.5, 0.4), (0.0, 0.1)), {"n": 4}, {"names": ["a"]},
                         ((0.1, 0.2), (0.3, 0.4), (0.5, 0.6)), 10.0)
    assert HorizonBlend.from_dict(blend.to_dict()) == blend
    with pytest.raises(BlendError, match="decoder_rms"):
        HorizonBlend((1,), ((1.0,),), decoder_rms=((0.1, 0.2),))
    with pytest.raises(BlendError, match=r"\[0, 1\]"):
        HorizonBlend((1,), ((1.5,),))
    with pytest.raises(BlendError, match="increasing"):
        HorizonBlend((3, 2), ((1.0,), (1.0,)))
    with pytest.raises(BlendError, match="fit it again"):
        HorizonBlend.from_dict({"knots": [1]})
    with pytest.raises(BlendError, match="2 channels"):
        blend.combine(np.zeros((1, 4, 3)), np.zeros((1, 4, 3)))
    with pytest.raises(BlendError, match="at least 2 windows"):
        fit_blend(*(np.zeros((1, 4, 2)),) * 3)


@pytest.fixture(scope="module")
def total_store(simulated_store):
    return simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=1)


@pytest.fixture(scope="module")
def blended(tiny_checkpoint, total_store, simulated_store, tmp_path_factory):
    """The tiny total-torque black-box model, given a blend fitted on other robots."""
    from robomorph.evaluation.calibrating import blend
    from robomorph.evaluation.requests import BlendConfig

    heldout = simulated_store(robots=6, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=7)
    out = str(tmp_path_factory.mktemp("blend") / "blended.ckpt")
    report = blend(BlendConfig(ckpt=tiny_checkpoint, data=heldout, out=out, n=6))
    return out, report


def test_calibrate_blend_gives_a_black_box_model_a_backbone_and_the_blend_by_default(blended, total_store):
    from robomorph.data.store import open_store
    from robomorph.inference.predictor import Predictor

    out, report = blended
    rms = report["rms"]
    # Physics wins the first step by far on a 6-step model; the blend is no worse than either on its windows.
    assert rms["physics"][0] < rms["decoder"][0]
    assert report["weight"][0] > 0.5
    pred = Predictor.from_checkpoint(out)
    assert pred.inputs == "total" and pred.physics is not None and pred.settings.mode == "blend"
    ds = open_store(total_store)
    u, y = ds.read("u")[:3], ds.read("y")[:3]
    c = CKPT_CONTEXT
    mixed = pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True)
    pred.configure(mode="none")
    decoder = pred.simulate(u[:, :c], y[:, :c], u[:, c:])
    pred.configure(mode="regression")  # the same backbone, no head needed
    physics = pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True)
    blend = pred.model.blend
    w = blend.weights(u.shape[1] - c)[None]
    w = w * blend.kept(physics.astype(np.float64), decoder.astype(np.float64))[..., None]  # the gate's share
    np.testing.assert_allclose(mixed, w * physics + (1 - w) * decoder, rtol=1e-4, atol=1e-6)
    assert np.abs(mixed - decoder).max() > 1e-4  # the physics moved it
    pred.configure(mode="blend")
    from robomorph.inference.hybrid import HybridError

    with pytest.raises(HybridError, match="no Gaussian head"):  # this decoder predicts no std
        pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True, return_std=True)


@pytest.fixture(scope="module")
def gaussian_blended(total_store, simulated_store, tmp_path_factory):
    """A tiny total-torque model with a Gaussian head, given a blend (smoothed, its default) on other robots."""
    from robomorph.evaluation.calibrating import blend
    from robomorph.evaluation.requests import BlendConfig
    from robomorph.training.fitting import fit
    from tests.conftest import tiny_fit_args

    runs = tmp_path_factory.mktemp("gauss")
    ckpt = fit(tiny_fit_args(total_store, runs, "gauss", model={"anchor": True, "gaussian": True, "loss": "nll"})
               ).best_ckpt
    heldout = simulated_store(robots=6, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=7)
    out = str(runs / "blended.ckpt")
    report = blend(BlendConfig(ckpt=ckpt, data=heldout, out=out, n=6))
    return out, heldout, report


def test_a_gaussian_models_blend_has_a_std_that_calibrate_then_rescales_in_blend_mode(gaussian_blended, total_store):
    from robomorph.data.store import open_store
    from robomorph.evaluation.calibrating import calibrate
    from robomorph.evaluation.requests import CalibrateConfig
    from robomorph.inference.predictor import Predictor

    out, heldout, _ = gaussian_blended
    pred = Predictor.from_checkpoint(out)
    ds = open_store(total_store)
    u, y = ds.read("u")[:3], ds.read("y")[:3]
    c = CKPT_CONTEXT
    mean, std = pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True, return_std=True)
    np.testing.assert_allclose(mean, pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True), rtol=1e-5, atol=1e-7)
    assert std.shape == mean.shape and np.all(np.isfinite(std)) and np.all(std > 0)
    calibrated_out = out.replace(".ckpt", "_cal.ckpt")
    calibrate(CalibrateConfig(ckpt=out, data=heldout, out=calibrated_out, n=6))
    pred = Predictor.from_checkpoint(calibrated_out)
    assert pred.calibration is not None and pred.calibration.source["physics_mode"] == "blend"
    _, calibrated = pred.simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True, return_std=True)
    np.testing.assert_allclose(calibrated, std * pred.calibration.factors(u.shape[1] - c)[None], rtol=1e-4)


def test_a_head_less_model_refuses_the_head_modes_in_one_line(blended, total_store):
    from robomorph.data.store import open_store
    from robomorph.inference.hybrid import HybridError
    from robomorph.inference.predictor import Predictor

    pred = Predictor.from_checkpoint(blended[0])
    ds = open_store(total_store)
    u, y = ds.read("u")[:1], ds.read("y")[:1]
    before = pred.settings
    for mode in ("learned", "fused"):
        with pytest.raises(HybridError, match="parameter head"):
            pred.configure(mode=mode)  # refused where it is asked for (issue 61), the settings left as they were
        assert pred.settings == before
    pred.configure(mode="refined")  # starts from the regression: no head needed
    out = pred.simulate(u[:, :CKPT_CONTEXT], y[:, :CKPT_CONTEXT], u[:, CKPT_CONTEXT:], at_rest=True)
    assert out.shape == (1, CKPT_HORIZON, 14) and np.all(np.isfinite(out))


def test_blend_without_weights_and_on_stores_without_parameters_is_refused(tiny_checkpoint, blended, total_store,
                                                                          linear_store, tmp_path):
    import subprocess
    import sys

    from robomorph.data.store import open_store
    from robomorph.inference.hybrid import HybridError
    from robomorph.inference.predictor import Predictor

    assert Predictor.from_checkpoint(tiny_checkpoint).settings.mode == "none"  # nothing fitted: the decoder
    pred = Predictor.from_checkpoint(blended[0])
    pred.model.blend = None
    ds = open_store(total_store)
    u, y = ds.read("u")[:1], ds.read("y")[:1]
    with pytest.raises(HybridError, match="calibrate --blend"):
        pred.simulate(u[:, :CKPT_CONTEXT], y[:, :CKPT_CONTEXT], u[:, CKPT_CONTEXT:])
    out = tmp_path / "x.ckpt"
    logs = linear_store(n=8, steps=CKPT_CONTEXT + CKPT_HORIZON, n_u=7, n_y=14)  # no catalogue robot behind them
    proc = subprocess.run([sys.executable, "-m", "robomorph.calibrate", "--ckpt", tiny_checkpoint, "--blend",
                           "--data", logs, "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "physics backbone" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_a_gaussian_models_blend_weighs_the_smoothed_physics_which_keeps_to_the_robot_not_the_decoder(
        gaussian_blended, total_store):
    from robomorph.data.store import open_store
    from robomorph.inference.predictor import Predictor

    out, _, report = gaussian_blended
    pred = Predictor.from_checkpoint(out)
    blend = pred.model.blend
    assert blend.physics_mode == "smoothed" and report["blend"]["physics_mode"] == "smoothed"
    assert blend.gate == float("inf")  # a smoothed horizon does not run away from its decoder
    ds = open_store(total_store)
    u, y = ds.read("u")[:3], ds.read("y")[:3]
    c = CKPT_CONTEXT
    args = (u[:, :c], y[:, :c], u[:, c:])
    mixed, mixed_std = pred.simulate(*args, at_rest=True, return_std=True)
    pred.configure(mode="smoothed")
    smoothed, smoothed_std = pred.simulate(*args, at_rest=True, return_std=True)
    pred.configure(mode="none")
    decoder, decoder_std = pred.simulate(*args, return_std=True)
    want, want_std = blend.combine(smoothed, decoder, smoothed_std, decoder_std)
    np.testing.assert_allclose(mixed, want, rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(mixed_std, want_std, rtol=1e-4, atol=1e-7)
    pred.configure(mode="regression")  # the identified robot simulated forward, from the same estimate
    forward = pred.simulate(*args, at_rest=True)
    truth = y[:, c:, 7:]
    err = lambda p: np.sqrt(np.mean((p[..., 7:] - truth) ** 2))  # noqa: E731
    # Over one second the forward simulation has not left yet (tests/identification/test_smoother.py follows one that
    # has): the smoothed horizon stays with it, not with this 6-step decoder.
    assert err(smoothed) < 0.2 * err(decoder) and err(smoothed) < 2 * err(forward)
    assert np.all(np.isfinite(smoothed_std)) and np.all(smoothed_std > 0)
    # The query outputs are never read: poisoning them changes nothing.
    pred.configure(mode="smoothed")
    np.testing.assert_array_equal(pred.simulate(*args, at_rest=True), smoothed)
    # Every smoothed window is tallied (the blend's three, then three smoothed twice).
    tally = pred.hybrid().smoothing
    assert tally["windows"] == 9 and 0 <= tally["staged"] <= 9
    assert all(1 <= k <= u.shape[1] - c for k in tally["handed_from"])


def test_the_smoothed_mode_refuses_commands_and_decoders_without_a_std(blended, total_store):
    from robomorph.data.store import open_store
    from robomorph.inference.hybrid import HybridError
    from robomorph.inference.predictor import Predictor

    pred = Predictor.from_checkpoint(blended[0])
    ds = open_store(total_store)
    u, y = ds.read("u")[:1], ds.read("y")[:1]
    pred.configure(mode="smoothed")
    with pytest.raises(HybridError, match="no Gaussian head"):
        pred.simulate(u[:, :CKPT_CONTEXT], y[:, :CKPT_CONTEXT], u[:, CKPT_CONTEXT:])
    pred.hybrid().inputs = "command"
    with pytest.raises(HybridError, match="total torques"):
        pred.simulate(u[:, :CKPT_CONTEXT], y[:, :CKPT_CONTEXT], u[:, CKPT_CONTEXT:])


def test_evaluate_tallies_each_smoothed_window_once(gaussian_blended, tmp_path):
    """The std probe on the first window is not one of the windows: the tally counts n."""
    import json

    from robomorph.evaluation.evaluator import evaluate
    from robomorph.evaluation.requests import EvaluateConfig

    out, heldout, _ = gaussian_blended
    evaluate(EvaluateConfig(ckpt=out, data=heldout, out=str(tmp_path / "ev"), n=3, baselines=(), samples=0))
    meta = json.loads((tmp_path / "ev" / "metrics.json").read_text())["meta"]
    assert meta["smoothing"]["windows"] == 3 and meta["smoothing"]["staged"] <= 3
