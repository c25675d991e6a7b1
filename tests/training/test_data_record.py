"""What a model records of its training data, and the check that data fits the model."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from robomorph.core.errors import RoboMorphError
from robomorph.data.fingerprints import fingerprint
from robomorph.inference.checkpoint import CheckpointError
from robomorph.training.data_record import check_channels, data_info
from tests.conftest import linear_system, write_store


def test_the_record_names_the_channels_window_and_stores_with_their_fingerprints(tmp_path):
    stores = [write_store(tmp_path / f"{i}.zarr", *linear_system(4, 20, seed=i), attrs={"dt": 0.02}) for i in (0, 1)]
    dm = SimpleNamespace(u_names=["u0", "u1"], y_names=["y0", "y1", "y2"], dt=np.float32(0.02), context_len=10,
                         horizon=10, stores=stores)
    info = data_info(dm)
    assert info["inputs"] == "total"  # a DataModule without the option: the paper's input
    assert info["store_fingerprints"] == {s: fingerprint(s) for s in stores}
    assert len(set(info["store_fingerprints"].values())) == 2
    assert json.loads(json.dumps(info)) == info  # saved in the checkpoint as it is
    assert (info["u_names"], info["y_names"], info["context_len"], info["horizon"]) == (["u0", "u1"],
                                                                                        ["y0", "y1", "y2"], 10, 10)


def test_the_data_must_have_the_model_channels():
    dm = SimpleNamespace(n_u=2, n_y=3)
    check_channels(dm, 2, 3)
    with pytest.raises(RoboMorphError, match="the model has no n_u/n_y: pass them"):
        check_channels(dm, None, 3)
    with pytest.raises(CheckpointError, match="the data has n_u=2, n_y=3 but the model was built for n_u=2, n_y=4"):
        check_channels(dm, 2, 4)
