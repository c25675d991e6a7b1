"""The learned residual end to end: trained on a prior store, read back, predicting prior + correction."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.data.store import open_store
from robomorph.inference.predictor import PredictionError, Predictor
from robomorph.training.module import ModelSettingsError
from tests.conftest import linear_system, tiny_fit_args, write_store
from tests.data.test_priors import CONTEXT, HORIZON, prior_store


@pytest.fixture(scope="module")
def residual_run(tmp_path_factory):
    from robomorph.training.fitting import fit

    folder = tmp_path_factory.mktemp("residual")
    store = prior_store(folder / "p.zarr", n=32)
    args = tiny_fit_args(store, folder / "runs", "res", data={"context_len": CONTEXT, "horizon": HORIZON},
                         model={"recenter": True})
    args["data"]["recenter"] = True
    return store, fit(args)


def test_fit_on_a_prior_store_trains_a_residual_model_and_records_its_priors(residual_run):
    store, result = residual_run
    pred = Predictor.from_checkpoint(result.last_ckpt)
    assert pred.model.config.residual
    assert pred.residual == open_store(store).attrs["prior"]
    # The correction's unit: the prior's RMS error per step on the training rows, in normalized outputs.
    scale = pred.model.net.prior_scale
    assert torch.all(scale[:HORIZON] > 0) and torch.equal(scale[HORIZON:], scale[HORIZON - 1].expand_as(scale[HORIZON:]))
    ds = open_store(store)
    err = np.sqrt(((ds.read("y")[:, CONTEXT:] - ds.read("prior")).astype(np.float64) ** 2).mean((0, 1)))
    ratio = (scale[:HORIZON] * pred.model.normalizer.y_std).mean(0).numpy() / err
    assert np.all((ratio > 0.5) & (ratio < 2.0))  # the training rows' error, of the same size as all rows'


def test_the_prediction_is_the_prior_plus_the_networks_correction(residual_run):
    store, result = residual_run
    pred = Predictor.from_checkpoint(result.last_ckpt)
    ds = open_store(store)
    u, y, prior = ds.read("u")[:3], ds.read("y")[:3], ds.read("prior")[:3]
    out = pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior)
    assert out.shape == prior.shape and out.dtype == u.dtype
    again = pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior)
    np.testing.assert_array_equal(out, again)
    # One window alone, and a prior moved by d: the prediction moves by d where the correction does not see it.
    one = pred.simulate(u[0, :CONTEXT], y[0, :CONTEXT], u[0, CONTEXT:], prior=prior[0])
    np.testing.assert_allclose(one, out[0], atol=1e-5)
    model = pred.model
    t = [torch.as_tensor(a) for a in (u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior)]
    with torch.no_grad():
        by_hand = model(*t[:3], prior=t[3]).numpy()
    np.testing.assert_allclose(out, by_hand, atol=1e-6)


def test_a_residual_prediction_does_not_read_the_query_outputs(residual_run):
    store, result = residual_run
    pred = Predictor.from_checkpoint(result.last_ckpt)
    ds = open_store(store)
    u, y, prior = ds.read("u")[:2], ds.read("y")[:2], ds.read("prior")[:2]
    base = pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior)
    y_other = y.copy()
    y_other[:, CONTEXT:] += 10.0  # the true query outputs are not an argument: nothing can leak
    np.testing.assert_array_equal(base, pred.simulate(u[:, :CONTEXT], y_other[:, :CONTEXT], u[:, CONTEXT:],
                                                      prior=prior))


def test_prior_errors_are_clear(residual_run, tiny_checkpoint):
    store, result = residual_run
    pred = Predictor.from_checkpoint(result.last_ckpt)
    ds = open_store(store)
    u, y, prior = ds.read("u")[:2], ds.read("y")[:2], ds.read("prior")[:2]
    with pytest.raises(PredictionError, match=r"prior must have shape \(B, Th, n_y\)"):
        pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior[:, :5])
    bad = prior.copy()
    bad[0, 3, 1] = np.nan
    with pytest.raises(PredictionError, match="NaN or inf"):
        pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=bad)
    plain = Predictor.from_checkpoint(tiny_checkpoint)
    assert plain.residual is None
    with pytest.raises(PredictionError, match="not a residual model"):
        plain.prior_predictor  # noqa: B018
    with pytest.raises(PredictionError, match="not a residual model"):
        plain.simulate(np.zeros((30, 7)), np.zeros((30, 14)), np.zeros((10, 7)), prior=np.zeros((10, 14)))


def test_a_residual_model_trains_on_prior_stores_only(tmp_path):
    import types

    from robomorph.data.datamodule import RoboMorphDataModule
    from robomorph.training.module import MetaModule

    u, y = linear_system(16, CONTEXT + HORIZON)
    dm = RoboMorphDataModule(write_store(tmp_path / "plain.zarr", u, y), context_len=CONTEXT, horizon=HORIZON)
    assert not dm.residual  # robomorph fit links it: a plain store trains a plain model
    module = MetaModule(n_u=2, n_y=3, context_len=CONTEXT, residual=True, d_model=16, n_head=2, n_layer=1, patch=5,
                        max_context=64, max_horizon=64)
    module._trainer = types.SimpleNamespace(datamodule=dm)  # private: setup reads the trainer's datamodule
    with pytest.raises(ModelSettingsError, match="prior stores"):
        module.setup("fit")
    with pytest.raises(ModelSettingsError, match="--model.anchor"):
        MetaModule(n_u=2, n_y=3, residual=True, anchor=True)


def test_an_exported_residual_model_predicts_the_same(residual_run, tmp_path):
    from robomorph.model.files import export

    store, result = residual_run
    export(result.last_ckpt, str(tmp_path / "model"))
    a, b = Predictor.from_checkpoint(result.last_ckpt), Predictor.from_pretrained(str(tmp_path / "model"))
    assert b.residual == a.residual and torch.equal(b.model.net.prior_scale, a.model.net.prior_scale)
    ds = open_store(store)
    u, y, prior = ds.read("u")[:3], ds.read("y")[:3], ds.read("prior")[:3]
    np.testing.assert_array_equal(a.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior),
                                  b.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], prior=prior))
