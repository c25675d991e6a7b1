"""The models shipped in the package: found by a bare name, offline, and predicting; a name no
shipped model has is refused naming those there are."""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import numpy as np
import pytest

from robomorph.evaluation.baselines import constant_velocity
from robomorph.inference.checkpoint import CheckpointError
from robomorph.model import pretrained
from robomorph.predictor import Predictor

SHIPPED = "realistic-arms-60hz"
ROOT = Path(__file__).resolve().parents[2]


def _ur5e_window(seed: int = 0, context: int = 200, horizon: int = 60):
    """A UR5e-shaped window (6 torques, EE pose and 6 joint angles at 60 Hz): smooth joint motion."""
    rng = np.random.default_rng(seed)
    t = np.arange(context + horizon) / 60.0
    q = 0.3 * np.sin(2 * np.pi * rng.uniform(0.1, 0.3, 6) * t[:, None] + rng.uniform(0, 6, 6)) + [0, -1.2, 1.5, -1.8, -1.6, 0]
    pose = np.tile([0.4, 0.1, 0.5, 0.0, 0.7071, 0.0, 0.7071], (len(t), 1)) + 0.01 * np.sin(t)[:, None]
    u = 5 * np.sin(2 * np.pi * 0.2 * t[:, None] + np.arange(6)) + [0, -40, -15, -2, 0, 0]
    y = np.concatenate([pose, q], axis=1)
    return (a.astype(np.float32) for a in (u[:context], y[:context], u[context:], y[context:]))


def test_the_shipped_model_is_listed_and_ships_in_the_wheel():
    assert SHIPPED in pretrained.available()
    folder = pretrained.SHIPPED_DIR / SHIPPED
    assert {"model.safetensors", "config.json", "README.md"} <= set(os.listdir(folder))
    assert (folder / "model.safetensors").stat().st_size < 8 * 2**20  # a few MB, as a package file should be
    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["robomorph"]
    assert "**/*.safetensors" in globs and "**/*.json" in globs


def test_a_bare_name_loads_the_shipped_model_offline_and_predicts(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # nothing of that name beside the caller: the package's copy is read
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    pred = Predictor.from_pretrained(SHIPPED, device="cpu")
    u_ctx, y_ctx, u_q, _ = _ur5e_window()
    mean, std = pred.simulate(u_ctx, y_ctx, u_q, return_std=True)
    assert mean.shape == std.shape == (60, 13)
    assert np.isfinite(mean).all() and (std > 0).all()
    # The same model read from its folder's path predicts the same; and again, to the bit.
    again = Predictor.from_pretrained(str(pretrained.SHIPPED_DIR / SHIPPED), device="cpu").simulate(u_ctx, y_ctx, u_q)
    np.testing.assert_array_equal(mean, again)


def test_the_shipped_model_corrects_constant_velocity_not_replaces_it():
    # Anchored on kinematics: its first step stays within a few mrad of constant velocity's on smooth motion,
    # where a model predicting from scratch starts tens of mrad away (the UR5 zero-shot model: 45 mrad).
    pred = Predictor.from_pretrained(SHIPPED, device="cpu")
    assert pred.model.kinematic_points == 2
    u_ctx, y_ctx, u_q, _ = _ur5e_window(seed=1)
    mean = pred.simulate(u_ctx, y_ctx, u_q)
    cv = constant_velocity(u_ctx[None], y_ctx[None], u_q[None])[0]
    assert np.abs(mean[0, 7:] - cv[0, 7:]).max() < 5e-3


def test_a_name_no_shipped_model_has_is_refused_naming_the_shipped_ones(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(CheckpointError, match=f"neither a model folder nor a shipped model.*{SHIPPED}"):
        Predictor.from_pretrained("no-such-model", device="cpu")


def test_a_path_is_read_as_a_path_even_where_a_shipped_name_is_in_it(tmp_path):
    # A folder path of the same last name is the user's, never the package's copy.
    with pytest.raises(CheckpointError):
        Predictor.from_pretrained(str(tmp_path / SHIPPED), device="cpu")
