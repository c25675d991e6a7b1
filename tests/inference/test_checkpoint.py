"""Checkpoint reading for inference: architecture from hyper-parameters, old checkpoints, refused files."""

import dataclasses

import numpy as np
import pytest
import torch

from robomorph.inference.checkpoint import (
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
        if f.name not in ("n_u", "n_y", "n_params"):  # n_params follows --model.physics
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


def test_fit_checkpoints_hold_only_what_a_weights_only_load_rebuilds(tiny_checkpoint):
    # The reader allows no extra type: every checkpoint fit writes (weights, optimizer and
    # scheduler state, callback state, hyper-parameters, data record) must be plain data.
    ckpt = torch.load(tiny_checkpoint, map_location="cpu", weights_only=True)
    assert {"state_dict", "optimizer_states", "lr_schedulers", "callbacks", "hyper_parameters",
            DATA_INFO_KEY} <= set(ckpt)


@pytest.mark.parametrize("zipped", [True, False])
def test_checkpoints_in_the_layout_fit_writes_load_with_their_calibration(tiny_checkpoint, tmp_path, zipped):
    from robomorph.inference.calibration import CALIBRATION_KEY, StdCalibration

    ckpt = load_checkpoint_file(tiny_checkpoint)
    # Written as earlier versions wrote it (torch.save of Lightning's dict; optionally in torch's
    # pre-zip serialization), with a calibration as calibrate stores it (plain lists).
    cal = StdCalibration((1, 10), ((1.0,) * 14, (2.0,) * 14), "nll", {"split": "val", "coverage": {"steps": [1]}})
    ckpt["hyper_parameters"]["gaussian"] = False
    ckpt[CALIBRATION_KEY] = cal.to_dict()
    path = tmp_path / "written_before.ckpt"
    torch.save(ckpt, path, _use_new_zipfile_serialization=zipped)
    old = load_checkpoint_file(str(path))
    assert old["global_step"] == ckpt["global_step"] and old[CALIBRATION_KEY] == cal.to_dict()
    for key, value in ckpt["state_dict"].items():
        assert torch.equal(old["state_dict"][key], value)
    with pytest.raises(CheckpointError, match="no Gaussian head"):
        load_trained(str(path))  # read whole, then checked as before
    del ckpt[CALIBRATION_KEY]
    torch.save(ckpt, path, _use_new_zipfile_serialization=zipped)
    u, y, q = torch.randn(2, 30, 7), torch.randn(2, 30, 14), torch.randn(2, 20, 7)
    with torch.no_grad():
        assert torch.equal(load_trained(str(path))[0](u, y, q), load_trained(tiny_checkpoint)[0](u, y, q))


def test_a_file_with_other_objects_is_refused_in_one_line_naming_it(tmp_path):
    import numpy as np

    path = tmp_path / "numpy.ckpt"
    torch.save({"state_dict": {}, "hyper_parameters": {"dt": np.float64(0.01)}}, path)
    with pytest.raises(CheckpointError) as err:
        load_checkpoint_file(str(path))
    text = str(err.value)
    assert text.startswith(f"{path} contains objects that are not allowed") and "numpy" in text and "\n" not in text


@pytest.mark.parametrize("content", [b"hello world", b"PK\x03\x04" + b"\x00" * 64])
def test_a_corrupt_file_is_named_as_such(tmp_path, content):
    path = tmp_path / "bad.ckpt"
    path.write_bytes(content)
    with pytest.raises(CheckpointError, match="is not a readable checkpoint") as err:
        load_checkpoint_file(str(path))
    assert "\n" not in str(err.value)
    with pytest.raises(CheckpointError, match="checkpoint not found"):
        load_checkpoint_file(str(tmp_path / "absent.ckpt"))
