"""The demo's closing table (the rest of the demo is the commands it calls, tested in their rooms)."""

import numpy as np

from robomorph.evaluation.horizons import horizon_report
from robomorph.reproduction.demo import horizon_summary

NAMES = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]


def test_demo_ends_with_the_horizon_table_of_model_hold_and_nominal_physics():
    y = np.random.default_rng(0).normal(size=(3, 12, len(NAMES)))
    preds = {name: y + 0.001 * (k + 1) for k, name in enumerate(("model", "hold", "arx", "nominal_physics"))}
    res = {"meta": {"n": 3, "context_len": 20}, "horizons": horizon_report(y, preds, NAMES, 0.1, [1, 12])}
    text = horizon_summary(res)
    cells = [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if line.startswith("|")]
    assert "3 held-out robots" in text and cells[0][2:] == ["step 1 (0.1 s)", "step 12 (1.2 s)"]
    rows = [r for r in cells if r[0].startswith("joints")]
    assert [r[1] for r in rows] == ["model", "hold", "nominal_physics"]
    assert rows[1][2:] == ["2", "2"]  # hold is off by 2 mrad on every joint here


def test_the_demo_gives_a_total_torque_model_its_blend_before_calibrating(tiny_checkpoint, tmp_path):
    import shutil

    from robomorph.inference.checkpoint import load_trained
    from robomorph.reproduction.demo import calibrate_std

    ckpt = str(tmp_path / "best.ckpt")
    shutil.copy(tiny_checkpoint, ckpt)
    assert load_trained(ckpt)[0].blend is None
    assert calibrate_std(ckpt) is False  # no Gaussian head to calibrate, but the blend is fitted
    model, info = load_trained(ckpt)
    assert info["inputs"] == "total" and model.blend is not None and model.blend.physics is not None
