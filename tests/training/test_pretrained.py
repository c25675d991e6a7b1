"""Starting from a pretrained model: weights, normalization by ``normalization_from``,
freezing, and the refusals of channels and architectures that do not fit."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from robomorph.data.statistics import Stats
from robomorph.inference.checkpoint import CheckpointError
from robomorph.training.module import MetaModule
from robomorph.training.pretrained import IO_LAYERS, start_from

TINY = {"n_u": 2, "n_y": 3, "d_model": 16, "n_head": 2, "n_layer": 1, "patch": 5, "max_context": 40, "max_horizon": 40}
STATS = Stats(np.array([0.5, -1.0]), np.array([2.0, 0.5]), np.array([0.1, 0.2, -0.3]), np.array([0.3, 1.5, 0.7]))


def _module(seed: int, **kw) -> MetaModule:
    torch.manual_seed(seed)
    return MetaModule(**{**TINY, **kw})


@pytest.fixture
def pretrained(tmp_path):
    """A checkpoint file of a module with its own weights and statistics, and that module."""
    source = _module(0)
    source.normalizer.set_stats(STATS)
    source.stats_ready.fill_(True)
    path = tmp_path / "pre.ckpt"
    torch.save({"hyper_parameters": dict(source.hparams), "state_dict": source.state_dict()}, path)
    return str(path), source


def _same(a: MetaModule, b: MetaModule, prefix: str) -> bool:
    theirs = b.state_dict()
    return all(torch.equal(v, theirs[k]) for k, v in a.state_dict().items() if k.startswith(prefix))


def test_the_weights_come_and_the_statistics_are_left_to_the_new_data(pretrained):
    path, source = pretrained
    target = _module(1)
    assert not _same(target, source, "net.")
    start_from(target, path)
    assert _same(target, source, "net.")
    assert not bool(target.stats_ready)  # setup computes them from this run's training data
    assert not _same(target, source, "normalizer.")


def test_normalization_from_source_brings_the_statistics_too(pretrained):
    path, source = pretrained
    target = _module(1, normalization_from="source")
    start_from(target, path)
    assert bool(target.stats_ready) and _same(target, source, "normalizer.") and _same(target, source, "net.")


def test_the_freeze_mode_applies_to_the_loaded_network(pretrained):
    target = _module(1, freeze="encoder")
    start_from(target, pretrained[0])
    assert {n.split(".")[0] for n, p in target.net.named_parameters() if p.requires_grad} == {"decoder", "head"}


def test_other_channels_need_reinit_io_which_keeps_only_the_io_layers_new(pretrained):
    path, source = pretrained
    with pytest.raises(CheckpointError, match="n_u=2, n_y=3; this model has n_u=4, n_y=3. Set reinit_io=true"):
        start_from(_module(1, n_u=4), path)
    target = _module(1, n_u=4, reinit_io=True)
    fresh = {k: v.clone() for k, v in target.state_dict().items()}
    start_from(target, path)
    for key, value in target.state_dict().items():
        io = any(key.startswith(f"net.{layer}.") for layer in IO_LAYERS)
        if io:
            assert torch.equal(value, fresh[key]), key
        elif key.startswith("net."):
            assert torch.equal(value, source.state_dict()[key]), key
    with pytest.raises(CheckpointError, match="normalization_from=source needs the checkpoint's channels"):
        start_from(_module(1, n_u=4, reinit_io=True, normalization_from="source"), path)


def test_another_architecture_or_protocol_is_refused_with_one_line(pretrained):
    path, _ = pretrained
    with pytest.raises(CheckpointError, match=r"does not match this architecture \(other shapes of \['net\."):
        start_from(_module(1, d_model=32), path)
    with pytest.raises(CheckpointError, match=r"does not match this architecture \(missing \['net\.decoder\.blocks\.1"):
        start_from(_module(1, n_layer=2), path)
    with pytest.raises(CheckpointError, match="normalization 'train_stats', this run uses 'paper_window'"):
        start_from(_module(1, normalization="paper_window"), path)
