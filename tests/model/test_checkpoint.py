"""Checkpoint reading for inference: architecture from hyper-parameters, old checkpoints."""

import dataclasses

import numpy as np
import pytest
import torch

from robomorph.model.checkpoint import (
    DATA_INFO_KEY,
    CheckpointError,
    TrainedModel,
    load_checkpoint_file,
    load_trained,
    model_config,
)
from robomorph.model.transformer import ModelConfig


def test_model_config_takes_the_architecture_and_defaults_for_the_rest():
    cfg = model_config({"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "lr": 1e-3, "freeze": "none"})
    assert (cfg.n_u, cfg.n_y, cfg.d_model, cfg.n_head) == (2, 3, 16, 2)
    assert cfg.patch == ModelConfig.patch and cfg.n_layer == ModelConfig.n_layer


def test_training_module_takes_its_defaults_from_the_model_config():
    import inspect

    from robomorph.training.module import MetaModule

    params = inspect.signature(MetaModule.__init__).parameters
    for f in dataclasses.fields(ModelConfig):
        if f.name not in ("n_u", "n_y"):
            assert params[f.name].default == f.default, f.name


def test_a_checkpoint_from_before_the_data_record_still_loads(tiny_checkpoint, tmp_path):
    ckpt = load_checkpoint_file(tiny_checkpoint)
    new, info = load_trained(tiny_checkpoint)
    assert info["context_len"] == 30
    # An older checkpoint: no data record, no context_len hyper-parameter.
    del ckpt[DATA_INFO_KEY]
    del ckpt["hyper_parameters"]["context_len"]
    old_path = tmp_path / "old.ckpt"
    torch.save(ckpt, old_path)
    old, old_info = load_trained(str(old_path))
    assert old_info is None
    g = torch.Generator().manual_seed(0)
    u, y, q = torch.randn(2, 30, 7, generator=g), torch.randn(2, 30, 14, generator=g), torch.randn(2, 20, 7, generator=g)
    with torch.no_grad():
        np.testing.assert_array_equal(old(u, y, q).numpy(), new(u, y, q).numpy())


def test_a_state_that_does_not_fit_its_hyper_parameters_is_refused(tiny_checkpoint, tmp_path):
    ckpt = load_checkpoint_file(tiny_checkpoint)
    ckpt["hyper_parameters"]["d_model"] = 32
    path = tmp_path / "bad.ckpt"
    torch.save(ckpt, path)
    with pytest.raises(CheckpointError, match="does not match its own hyper-parameters"):
        load_trained(str(path))
    ckpt["hyper_parameters"]["n_u"] = None
    torch.save(ckpt, path)
    with pytest.raises(CheckpointError, match="lacks n_u/n_y"):
        load_trained(str(path))


def test_anchor_adds_the_last_context_output():
    torch.manual_seed(0)
    cfg = ModelConfig(n_u=2, n_y=3, d_model=8, n_head=2, n_layer=1, patch=1, max_context=8, max_horizon=8)
    plain, anchored = TrainedModel(cfg), TrainedModel(cfg, anchor=True)
    anchored.load_state_dict(plain.state_dict())
    u, y, q = torch.randn(1, 4, 2), torch.randn(1, 4, 3), torch.randn(1, 5, 2)
    with torch.no_grad():
        torch.testing.assert_close(anchored(u, y, q) - plain(u, y, q), y[:, -1:].expand(1, 5, 3))
