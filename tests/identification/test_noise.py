"""Encoder noise measured in a context, and the regression weighted by it (robomorph.identification.noise)."""

import numpy as np
import pytest

from robomorph.core.config import from_dict
from robomorph.data.store import open_store
from robomorph.evaluation.physics import NominalPhysics
from robomorph.identification import noise
from robomorph.identification.identify import KINDS, ParameterSpace, lean_model
from robomorph.identification.regressor import RegressorIdentifier
from robomorph.sim.randomize import Randomizer
from robomorph.sim.recipe import Recipe
from tests.identification.test_extra_terms import DAMPING_ONLY

CONTEXT = 200


@pytest.fixture(scope="module")
def store(simulated_store):
    return open_store(simulated_store(robots=4, steps=CONTEXT, seed=13, randomization=DAMPING_ONLY))


def _solver(ds):
    recipe = from_dict(Recipe, ds.attrs["config"], "store config")
    model = lean_model(recipe.substeps, recipe.dt, recipe.gravity_compensation == "true_model")
    rz = Randomizer(model, recipe.randomization)
    space = ParameterSpace.of(rz, recipe.randomization, KINDS)
    return RegressorIdentifier(recipe, space, rz, "command"), space


def test_the_noise_measured_in_a_context_is_the_noise_added_and_clean_contexts_measure_below_the_floor(store):
    q = store.read("y").astype(np.float64)[..., 7:]
    rng = np.random.default_rng(0)
    for b in range(len(q)):
        assert noise.encoder_noise(q[b]) < noise.NOISE_FLOOR
        for std in (1e-5, 1e-4):
            got = noise.encoder_noise(q[b] + rng.normal(0, std, q[b].shape))
            assert abs(got / std - 1) < 0.25


def test_smoothing_by_the_measured_noise_lowers_the_damping_error_on_noisy_contexts(store):
    ds = store
    reg, space = _solver(ds)
    sim = NominalPhysics(ds.attrs, "command")
    y, u, params = ds.read("y").astype(np.float64), ds.read("u_cmd").astype(np.float64), ds.read("params")
    damping = space.index[[i for i, n in enumerate(space.names) if n.startswith("damping")]]
    rng = np.random.default_rng(1)
    plain, weighted = [], []
    for b in range(len(y)):
        base = sim.params(y[b, 0, 7:])
        q = y[b, :, 7:] + rng.normal(0, 1e-4, y[b, :, 7:].shape)
        measured = noise.encoder_noise(q)
        plain.append(np.abs(reg.fit(base, q, u[b])[damping] - params[b, damping]).mean())
        weighted.append(np.abs(reg.fit(base, q, u[b], noise=measured)[damping] - params[b, damping]).mean())
    assert np.mean(weighted) < 0.7 * np.mean(plain)


def test_a_clean_context_fits_to_the_bit_as_without_the_noise_argument(store):
    reg, _ = _solver(store)
    y, u = store.read("y").astype(np.float64), store.read("u_cmd").astype(np.float64)
    base = NominalPhysics(store.attrs, "command").params(y[0, 0, 7:])
    measured = noise.encoder_noise(y[0, :, 7:])
    np.testing.assert_array_equal(reg.fit(base, y[0, :, 7:], u[0], noise=measured), reg.fit(base, y[0, :, 7:], u[0]))


def test_the_end_of_a_noisy_context_is_denoised_by_the_simulation_and_a_slow_fit():
    t = np.arange(200) / 60.0
    truth = np.stack([np.sin(1.3 * t + k) for k in range(7)], axis=1)
    simulated = truth + 1e-3 * t[:, None] ** 2  # a simulation that drifts slowly away
    rng = np.random.default_rng(2)
    errors = []
    for _ in range(40):
        recorded = truth + rng.normal(0, 1e-4, truth.shape)
        end = noise.denoised_end(recorded - simulated, simulated)
        assert end.shape == (noise.END_WINDOW, 7)
        errors.append(end[-1] - truth[-1])
    # A quadratic's end over 20 samples keeps sqrt(9 / 20) of the noise; the raw last sample keeps all of it.
    assert np.sqrt(np.mean(np.square(errors))) < 0.75e-4
    assert noise.end_window(1e-4) == noise.END_WINDOW > noise.end_window(1e-5) >= 8
    assert noise.window(1e-4) > noise.window(1e-5) >= 5 and noise.window(1e-4) % 2 == 1


def test_the_new_terms_are_settings_named_by_the_key_and_validated():
    from robomorph.inference.settings import HybridSettings, SettingsError

    s = HybridSettings(mode="refined", offsets=True, coulomb=True, payload=True, denoise=True, refine_all=True)
    assert s.key == "refined+offsets+coulomb+payload+denoise+refineall"
    assert HybridSettings.from_key(s.key) == s.replace(workers=HybridSettings().workers)
    assert not HybridSettings().denoise and not HybridSettings().offsets  # off unless asked for
    with pytest.raises(SettingsError, match="denoise"):
        HybridSettings(denoise=1)
    # the denoising follows the commands' observer; the offsets apply to total torques too
    total = s.in_effect("total")
    assert not total.denoise and total.offsets and total.payload


@pytest.mark.slow
def test_on_noisy_contexts_the_denoised_hybrid_beats_the_plain_one_and_refining_every_kind_beats_both(simulated_store):
    from robomorph.inference.predictor import Predictor

    ds = open_store(simulated_store(robots=4, steps=CONTEXT + 60, seed=15))
    y, u = ds.read("y").astype(np.float64), ds.read("u_cmd").astype(np.float64)
    noisy = y.copy()
    noisy[:, :CONTEXT, 7:] += np.random.default_rng(3).normal(0, 1e-4, noisy[:, :CONTEXT, 7:].shape)
    truth = y[:, CONTEXT:, 7:]
    errors = {}
    for name, changes in (("plain", {"denoise": False}), ("denoise", {"denoise": True}),
                          ("refined", {"denoise": True, "mode": "refined", "refine_iters": 8, "refine_all": True})):
        pred = Predictor.from_arm("panda", calibrated=False).configure(**changes)
        out = pred.simulate(u[:, :CONTEXT], noisy[:, :CONTEXT], u[:, CONTEXT:], at_rest=np.ones(len(u), bool))
        errors[name] = float(np.sqrt(np.mean((np.asarray(out)[:, -1, 7:] - truth[:, -1]) ** 2)))
    assert errors["denoise"] < errors["plain"] and errors["refined"] < errors["denoise"]
