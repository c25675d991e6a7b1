"""Prior stores in the DataModule: each window's prior rides along, aligned; runs it cannot feed are refused."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph.data.datamodule import RoboMorphDataModule
from robomorph.data.priors import PriorError, prior_error_rms
from tests.conftest import linear_system, write_store

CONTEXT, HORIZON = 30, 20


def prior_store(path, n: int = 24, seed: int = 0, bias: float = 0.3, **record) -> str:
    """A prior store without simulation: a linear system's windows, the prior its query outputs plus ``bias``
    plus noise (a prior with an error to correct)."""
    u, y = linear_system(n, CONTEXT + HORIZON, seed=seed)
    rng = np.random.default_rng(seed)
    prior = y[:, CONTEXT:] + bias + 0.05 * rng.normal(size=y[:, CONTEXT:].shape)
    rec = {"source": "lin", "source_n": n, "source_seed": seed, "settings": "regression", "fields": {},
           "context": CONTEXT, "horizon": HORIZON, "offsets": [0], "arm": "panda", "inputs": "total", **record}
    return write_store(path, u, y, attrs={"dt": 0.01, "prior": rec},
                       extras={"prior": ((HORIZON, 3), "float32", prior.astype(np.float32))})


def _dm(stores, **kw) -> RoboMorphDataModule:
    args = dict(context_len=CONTEXT, horizon=HORIZON, batch_size=4, split=(0.5, 0.25, 0.25), val_subset=4)
    return RoboMorphDataModule(stores=stores, **{**args, **kw})


def test_batches_carry_each_windows_prior(tmp_path):
    from robomorph.data.store import open_store

    path = prior_store(tmp_path / "p.zarr")
    dm = _dm(path)
    assert dm.residual
    dm.setup()
    ds = open_store(path)
    y, prior = ds.read("y"), ds.read("prior")
    for split in ("train", "val"):
        dataset = getattr(dm, f"{split}_set")
        for row in range(len(dataset)):
            item, i = dataset[row], int(dataset.pairs[row][1])
            np.testing.assert_array_equal(item["prior_query"].numpy(), prior[i])
            np.testing.assert_array_equal(item["y_query"].numpy(), y[i, CONTEXT:])
    batch = next(iter(dm.train_dataloader()))
    assert batch["prior_query"].shape == batch["y_query"].shape == (4, HORIZON, 3)


def test_the_prior_error_is_measured_on_training_rows_only(tmp_path):
    from robomorph.data.store import open_store

    path = prior_store(tmp_path / "p.zarr")
    dm = _dm(path)
    dm.setup()
    rows = dm.splits[0]["train"]
    ds = open_store(path)
    expected = np.sqrt(((ds.read("y")[rows, CONTEXT:] - ds.read("prior")[rows]).astype(np.float64) ** 2).mean(0))
    np.testing.assert_allclose(dm.prior_error, expected, rtol=1e-6)
    assert dm.prior_error.shape == (HORIZON, 3)
    np.testing.assert_allclose(prior_error_rms([(np.ones((2, 5, 1)), np.zeros((2, 5, 1)))], 3), np.ones((3, 1)))


def test_a_shorter_horizon_takes_the_priors_first_steps(tmp_path):
    dm = _dm(prior_store(tmp_path / "p.zarr"), horizon=HORIZON // 2)
    dm.setup()
    assert dm.train_set[0]["prior_query"].shape == (HORIZON // 2, 3)


@pytest.mark.parametrize("kw, phrase", [
    ({"context_len": CONTEXT - 10}, f"use --data.context_len {CONTEXT}"),
    ({"horizon": HORIZON + 5, "context_len": CONTEXT - 5}, "context of 30 steps"),
    ({"window": "random"}, "--data.window start"),
    ({"context_min": 10}, "--data.window start and no --data.context_min"),
])
def test_windows_the_priors_do_not_cover_are_refused(tmp_path, kw, phrase):
    with pytest.raises(PriorError, match=phrase.replace("(", r"\(").replace(")", r"\)")):
        _dm(prior_store(tmp_path / "p.zarr"), **kw).setup()


def test_a_mix_of_prior_and_plain_stores_or_of_settings_is_refused(tmp_path):
    u, y = linear_system(8, CONTEXT + HORIZON)
    plain = write_store(tmp_path / "plain.zarr", u, y)
    with pytest.raises(PriorError, match="holds no priors"):
        _dm([prior_store(tmp_path / "p.zarr"), plain]).setup()
    other = prior_store(tmp_path / "q.zarr", seed=1, settings="regression+payload")
    with pytest.raises(PriorError, match="settings"):
        _dm([prior_store(tmp_path / "p2.zarr"), other]).setup()


def test_the_formulation_must_be_the_priors(tmp_path):
    with pytest.raises(PriorError, match="predicted from the command formulation.*use --data.inputs command"):
        _dm(prior_store(tmp_path / "p.zarr", inputs="command"), inputs="total").setup()
