"""The hybrid model: a parameter head on the encoder and the robot simulated with its estimate."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import torch

from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

# The calibration key of a new command hybrid's default mode (every recorded switch on).
KEY = "regression+obs+springs+debias+coulomb+payload+denoise"


@pytest.fixture(scope="module")
def command_store(simulated_store):
    return simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=3)


@pytest.fixture(scope="module")
def hybrid_ckpt(command_store, tmp_path_factory) -> str:
    from robomorph.training.fitting import fit

    args = tiny_fit_args(command_store, tmp_path_factory.mktemp("runs"), "hybrid", steps=6,
                         data={"inputs": "command"}, model={"physics": "amortized", "anchor": True})
    return fit(args).best_ckpt


def _windows(store: str, inputs: str = "command", n: int = 3):
    from robomorph.data.store import open_store

    ds = open_store(store)
    u, y, p = ds.read_inputs(inputs)[:n], ds.read("y")[:n], ds.read("params")[:n]
    c = CKPT_CONTEXT
    return u[:, :c], y[:, :c], u[:, c:], y[:, c:], p.astype(np.float64), dict(ds.attrs)


def test_backbone_with_the_true_parameters_reproduces_the_recorded_robot(command_store):
    """The backbone's rollouts are the generator's physics: with each robot's stored
    parameters, from rest, the horizon equals the recorded outputs."""
    from robomorph.identification.backbone import PhysicsBackbone, parameter_layout

    uc, yc, uq, yq, params, attrs = _windows(command_store)
    with PhysicsBackbone(parameter_layout(attrs), "command", nthread=1) as bb:
        pred = bb.simulate(params, yc[..., 7:], uc, uq, np.zeros((len(uc), 7)), yc[:, -1, 3:7])
        assert pred.shape == yq.shape
        np.testing.assert_allclose(pred, yq, atol=2e-6)  # float32 storage
        # Another robot (the catalogue's) moves differently, so the comparison can fail.
        cat = np.stack([bb.catalogue(q) for q in yc[:, 0, 7:]])
        other = bb.simulate(cat, yc[..., 7:], uc, uq, np.zeros((len(uc), 7)), yc[:, -1, 3:7])
        assert np.abs(other - yq).max() > 1e-3


def test_backbone_threads_do_not_change_the_result(command_store):
    from robomorph.identification.backbone import PhysicsBackbone, parameter_layout

    uc, yc, uq, _, params, attrs = _windows(command_store)
    outs = []
    for nthread in (1, 2):
        with PhysicsBackbone(parameter_layout(attrs), "command", nthread=nthread) as bb:
            outs.append(bb.simulate(params, yc[..., 7:], uc, uq, np.zeros((len(uc), 7)), yc[:, -1, 3:7]))
    np.testing.assert_array_equal(outs[0], outs[1])


def test_fewer_physics_substeps_simulate_the_later_horizon_at_a_coarser_step(command_store):
    """``substeps`` is the physics step of the horizon after its first ``FINE_STEPS``: those stay
    the generator's to the bit, the later ones are a real coarser integration (they differ)
    that stays within a fraction of a milliradian of it."""
    from robomorph.identification.backbone import BackboneError, PhysicsBackbone, parameter_layout

    uc, yc, uq, yq, params, attrs = _windows(command_store)
    layout = parameter_layout(attrs)
    ss = int(layout["recipe"]["substeps"])
    with PhysicsBackbone(layout, "command", nthread=1, substeps=ss // 2) as bb:
        assert (bb.substeps, bb.coarse) == (ss, ss // 2)
        bb.FINE_STEPS = 20  # the test's horizon is shorter than the default's second
        coarse = bb.simulate(params, yc[..., 7:], uc, uq, np.zeros((len(uc), 7)), yc[:, -1, 3:7])
        assert bb.ident.model.opt.timestep == pytest.approx(attrs["dt"] / ss)
        assert all(m.opt.timestep == bb.ident.model.opt.timestep for m in bb.ident.engine.models)  # restored
    np.testing.assert_allclose(coarse[:, :20], yq[:, :20], atol=2e-6)  # float32 storage
    joints = (coarse - yq)[:, 20:, 7:]
    assert np.abs(joints).max() > 1e-7 and np.sqrt(np.mean(joints ** 2)) < 3e-4
    for bad in (0, -2, 2.5, True):
        with pytest.raises(BackboneError, match="positive integer"):
            PhysicsBackbone(layout, "command", nthread=1, substeps=bad)


def test_the_default_coarse_step_is_a_240th_of_a_second_never_finer_than_the_recipes(command_store):
    import dataclasses

    from robomorph.identification.backbone import PhysicsBackbone, coarse_substeps, parameter_layout

    layout = parameter_layout(_windows(command_store)[-1])
    with PhysicsBackbone(layout, "command", nthread=1) as bb:
        assert bb.coarse == coarse_substeps(bb.recipe) == round(bb.recipe.dt * 240)
        for dt, substeps, expected in ((1 / 60, 8, 4), (1 / 60, 2, 2), (1 / 30, 8, 8), (1 / 120, 8, 2), (1 / 600, 4, 1)):
            assert coarse_substeps(dataclasses.replace(bb.recipe, dt=dt, substeps=substeps)) == expected


def test_the_predictor_simulates_at_the_physics_substeps_asked_for(hybrid_ckpt, command_store):
    from robomorph.inference.predictor import Predictor

    uc, yc, uq, yq, _, attrs = _windows(command_store, n=1)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(substeps=attrs["substeps"])  # the generator's own step throughout
    exact = p.simulate(uc, yc, uq, at_rest=True)
    assert p.hybrid().backbone.coarse == attrs["substeps"]
    p.configure(substeps=attrs["substeps"] // 2)
    p.hybrid().backbone.FINE_STEPS = 20  # the test's horizon is shorter than the default's second
    coarse = p.simulate(uc, yc, uq, at_rest=True)
    assert p.hybrid().backbone.coarse == attrs["substeps"] // 2
    np.testing.assert_array_equal(coarse[:, :20], exact[:, :20])
    assert np.abs(coarse - exact).max() > 0 and np.sqrt(np.mean((coarse - exact)[..., 7:] ** 2)) < 3e-4
    p.configure(substeps=attrs["substeps"])
    np.testing.assert_array_equal(p.simulate(uc, yc, uq, at_rest=True), exact)


def test_parameter_head_never_sees_the_query(hybrid_ckpt, command_store):
    """Poisoned query: the parameters and the prediction up to step k do not move when the
    query outputs change (never given) or the query torques from step k on change."""
    from robomorph.inference.predictor import Predictor

    p = Predictor.from_checkpoint(hybrid_ckpt)
    uc, yc, uq, _, _, _ = _windows(command_store)
    hyb = p.hybrid()
    t = [torch.as_tensor(a, dtype=torch.float32) for a in (uc, yc, uq)]
    z1, _ = hyb.parameters(*t)
    z2, _ = hyb.parameters(t[0], t[1], t[2] * 100 + 7)
    np.testing.assert_array_equal(z1, z2)
    k = 20
    poisoned = uq.copy()
    poisoned[:, k:] += 5.0
    a = p.simulate(uc, yc, uq, at_rest=True)
    b = p.simulate(uc, yc, poisoned, at_rest=True)
    # y at step j (1-based) depends on the torques of query steps < j - 1 and the last context torque.
    np.testing.assert_array_equal(a[:, :k + 1], b[:, :k + 1])
    assert np.abs(a[:, k + 2:] - b[:, k + 2:]).max() > 0


def test_hybrid_predictor_equals_the_training_module(hybrid_ckpt, command_store):
    """Predictor.from_checkpoint and the module it was trained as give the same prediction."""
    from robomorph.inference.hybrid import Hybrid
    from robomorph.inference.predictor import Predictor
    from robomorph.training.module import MetaModule

    p = Predictor.from_checkpoint(hybrid_ckpt)
    ckpt = torch.load(hybrid_ckpt, weights_only=False, map_location="cpu")
    module = MetaModule.load_from_checkpoint(hybrid_ckpt, map_location="cpu").eval()
    uc, yc, uq, _, _, _ = _windows(command_store)
    mean, std = p.simulate(uc, yc, uq, at_rest=True, return_std=True)
    hyb = Hybrid(module.trained_model, ckpt["robomorph_data"]["physics"], "command", p.settings_in_effect)
    t = [torch.as_tensor(a, dtype=torch.float32) for a in (uc, yc, uq)]
    m2, s2 = hyb.predict(*t, at_rest=True, return_std=True)
    hyb.close()
    np.testing.assert_allclose(mean, m2.astype(np.float32), rtol=0, atol=0)
    np.testing.assert_allclose(std, s2.astype(np.float32), rtol=0, atol=0)
    assert mean.shape == uq.shape[:2] + (14,) and np.all(std >= 0)


def test_hybrid_is_deterministic_and_modes_differ(hybrid_ckpt, command_store):
    from robomorph.inference.predictor import Predictor

    uc, yc, uq, _, _, _ = _windows(command_store, n=2)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    a = p.simulate(uc, yc, uq, at_rest=True, return_std=True)
    b = Predictor.from_checkpoint(hybrid_ckpt).simulate(uc, yc, uq, at_rest=True, return_std=True)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    p.configure(mode="none")  # the black-box decoder of the same checkpoint
    black = p.simulate(uc, yc, uq)
    assert black.shape == a[0].shape and np.abs(black - a[0]).max() > 0
    p.configure(mode="refined")
    refined = p.simulate(uc, yc, uq, at_rest=True)
    assert refined.shape == a[0].shape and np.all(np.isfinite(refined))
    assert p.hybrid().last_fits and all(f.evaluations <= p.settings.refine_iters for f in p.hybrid().last_fits)


def test_store_without_params_refuses_physics_in_one_line(tmp_path, store_factory, command_store):
    """Real logs (no catalogue robot, no params) train the black-box model; asking for the
    physics backbone is refused with one line and exit code 2."""
    from tests.conftest import linear_system

    u, y = linear_system(16, CKPT_CONTEXT + CKPT_HORIZON, n_u=7, n_y=14)
    store = store_factory(tmp_path / "log.zarr", u, y)
    cmd = [sys.executable, "-m", "robomorph.fit", "--data.stores", store, "--data.context_len", str(CKPT_CONTEXT),
           "--data.horizon", str(CKPT_HORIZON), "--model.physics", "amortized", "--model.patch", "5",
           "--model.d_model", "16", "--model.n_head", "2", "--model.n_layer", "1", "--trainer.max_steps", "2",
           "--runs_dir", str(tmp_path / "runs"), "--run", "x", "--wandb", "disabled"]
    out = subprocess.run(cmd, capture_output=True, text=True)
    assert out.returncode == 2, out.stderr[-2000:]
    lines = [x for x in out.stderr.strip().splitlines() if x.strip()]
    assert len(lines) == 1 and "--model.physics" in lines[0] and "Traceback" not in out.stderr


def test_black_box_checkpoints_have_no_parameter_head(tiny_checkpoint):
    """Old (black-box) checkpoints load as before: no parameter head, the decoder predicts."""
    from robomorph.inference.predictor import Predictor

    p = Predictor.from_checkpoint(tiny_checkpoint)
    assert p.physics is None and p.settings.mode == "none" and p.model.net.param_head is None
    ckpt = torch.load(tiny_checkpoint, weights_only=False, map_location="cpu")
    assert not any("param_head" in k for k in ckpt["state_dict"])
    with pytest.raises(Exception, match="no physics backbone"):
        p.hybrid()


def test_candidates_on_one_context_equal_their_rows_predicted_alone(hybrid_ckpt, command_store):
    """Model-predictive control asks for many torque sequences on one context: the robot is
    identified once, and each row equals its own prediction made alone."""
    from robomorph.inference.predictor import Predictor

    uc, yc, uq, _, _, _ = _windows(command_store, n=1)
    rng = np.random.default_rng(0)
    cand = uq[0][None] + rng.normal(0, 0.5, size=(5,) + uq.shape[1:]).astype(np.float32)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    batch = p.simulate(np.repeat(uc, 5, 0), np.repeat(yc, 5, 0), cand, at_rest=True)
    alone = np.concatenate([p.simulate(uc, yc, cand[k:k + 1], at_rest=True) for k in range(5)])
    np.testing.assert_allclose(batch, alone, rtol=0, atol=1e-6)
    assert np.abs(batch[0] - batch[1]).max() > 0  # other torques, another motion


def test_evaluate_physics_modes_and_refusal(hybrid_ckpt, tiny_checkpoint, command_store, tmp_path, capsys):
    """evaluate --physics picks the hybrid's mode; on a black-box checkpoint it is one line, exit 2."""
    import json

    from robomorph.evaluate import main

    out = tmp_path / "eval"
    assert main(["--ckpt", hybrid_ckpt, "--data", command_store, "--n", "2", "--baselines", "hold", "--plot-trajectories", "0",
                 "--physics", "learned", "--out", str(out)]) == 0
    res = json.loads((out / "metrics.json").read_text())
    assert res["horizons"]["steps"][0] == 1 and "model" in res["horizons"]["rms"]
    assert "calibration" in res["horizons"]  # the hybrid gives a std (parameter draws)
    assert res["meta"]["physics"]["mode"] == "learned" and res["meta"]["physics"]["observer"] is True
    assert ("mode `learned`, horizons from the observer's start velocity, std over one robot per column of the "
            "estimate's covariance and the observer's start velocity.") in (out / "table.md").read_text()
    assert res["meta"]["physics"]["points"] == "observed"  # no stored calibration: the default with the observer
    assert res["meta"]["physics"]["mixture"] is False  # the parameter head's estimate: no friction mixture
    capsys.readouterr()
    assert main(["--ckpt", tiny_checkpoint, "--data", command_store, "--n", "2", "--physics", "regression",
                 "--inputs", "total", "--out", str(tmp_path / "e2")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no physics backbone" in err[0]


def test_held_joints_predict_the_weighted_mean_of_the_friction_mixture(hybrid_ckpt, command_store):
    """Where a joint held still in the context, the regression's prediction is the weighted
    mean of the friction mixture's members, each simulated from where it leaves the context;
    the std holds their spread; one member gives the estimate alone."""
    from robomorph.inference.predictor import Predictor
    from robomorph.identification.stiction import FrictionMixture

    uc, yc, uq, _, _, _ = _windows(command_store, n=4)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.configure(mode="regression", debias=False)  # the regression's own estimate (debiased: test_debias.py)
    mean = p.simulate(uc, yc, uq, at_rest=True)
    hyb = p.hybrid()
    _, std = hyb.predict(*(torch.as_tensor(a) for a in (uc, yc, uq)), at_rest=True, return_std=True)  # uncalibrated
    held = hyb._held.copy()
    assert held.any()  # the short contexts of this store hold the wrist: the mixture is exercised
    params = hyb.identify(*(torch.as_tensor(a) for a in (uc, yc)), "regression", at_rest=True)
    mix = FrictionMixture(hyb.backbone.ident, hyb.settings.members)
    bb, q = hyb.backbone, yc[..., 7:].astype(np.float64)
    for b in range(len(uc)):
        est = hyb._regressor.fit(bb.catalogue(q[b, 0]), q[b], uc[b].astype(np.float64))
        members, w, qvel_end = mix.weigh(est, held[b], q[b], uc[b], np.zeros(7), bb.observe)
        np.testing.assert_allclose(params[b], w @ members)  # what a controller simulates with
        k = len(w)
        ys = bb.simulate(members, np.repeat(q[b:b + 1], k, 0), np.repeat(uc[b:b + 1], k, 0), np.repeat(uq[b:b + 1], k, 0),
                         np.zeros((k, 7)), np.repeat(yc[b:b + 1, -1, 3:7], k, 0), qvel_end)
        expect = np.einsum("k,khc->hc", w, ys)
        np.testing.assert_allclose(mean[b], expect, atol=2e-6)  # float32 output
        spread = np.sqrt(np.einsum("k,khc->hc", w, (ys - expect) ** 2))
        assert np.all(std[b] >= spread - 1e-9)
        if held[b].any():
            assert spread.max() > 0
    p.configure(members=1)
    alone = p.simulate(uc, yc, uq, at_rest=True)
    rows = held.any(axis=1)
    np.testing.assert_array_equal(alone[~rows], mean[~rows])
    assert np.abs(alone[rows] - mean[rows]).max() > 0


def test_scoring_gives_the_hybrid_where_each_robot_started(hybrid_ckpt, simulated_store):
    """Windows at random offsets: the scoring path tells the hybrid where each robot started (its
    springs' rest pose), as it tells the physics baselines; without it the springs are anchored
    at the first context sample and the prediction differs."""
    from robomorph.evaluation.scoring import MODEL, score_windows
    from robomorph.evaluation.windows import load_window
    from robomorph.inference.predictor import Predictor

    store = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON + 60, seed=5)
    p = Predictor.from_checkpoint(hybrid_ckpt)
    p.has_std = False
    p.configure(members=1)
    w = load_window(store, CKPT_CONTEXT, CKPT_HORIZON, 4, p.data_info, p.n_u, p.n_y, "random", 0, "command")
    moved = w.starts > 0
    assert moved.any()
    scored = score_windows(p, w, ()).preds[MODEL]
    u_ctx, y_ctx, u_q, _ = w.split()
    given = p.simulate(u_ctx, y_ctx, u_q, at_rest=~moved, anchor=w.y_first[:, 7:14])
    np.testing.assert_allclose(scored, given, rtol=0, atol=1e-6)
    default = p.simulate(u_ctx, y_ctx, u_q, at_rest=~moved)
    assert np.abs(default[moved] - given[moved]).max() > 1e-6


def test_each_physics_mode_keeps_its_own_std_calibration(hybrid_ckpt, simulated_store, tmp_path, capsys):
    """calibrate --physics M fits mode M's calibration and leaves the others' in place; the
    Predictor applies the one of the mode it predicts in (none for a mode never calibrated);
    --remove --physics M drops M's alone, and one mode keeps the single-calibration layout."""
    from robomorph.calibrate import main
    from robomorph.inference.calibration import CALIBRATION_KEY
    from robomorph.model.files import load_checkpoint_file
    from robomorph.inference.predictor import Predictor

    out = str(tmp_path / "cal.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=8)
    common = ["--data", heldout, "--n", "4"]
    assert main(["--ckpt", hybrid_ckpt, "--out", out, *common, "--physics", "regression"]) == 0
    assert load_checkpoint_file(out)[CALIBRATION_KEY]["source"]["physics_mode"] == "regression"  # the old layout
    assert main(["--ckpt", out, *common, "--physics", "learned"]) == 0
    assert "physics mode learned" in capsys.readouterr().out
    p = Predictor.from_checkpoint(out)
    assert set(p.model.calibrations) == {KEY, "learned+obs"}  # fitted with the observer on
    scales = {}
    for mode in ("regression", "learned", "fused"):
        p.use_physics(mode)
        scales[mode] = None if p.calibration is None else p.calibration.scale
    assert scales["fused"] is None and scales["regression"] != scales["learned"]
    assert Predictor.from_checkpoint(hybrid_ckpt).calibration is None  # --out left the original alone
    assert main(["--ckpt", out, "--remove", "--physics", "learned"]) == 0
    kept = Predictor.from_checkpoint(out)
    assert set(kept.model.calibrations) == {KEY} and kept.calibration.scale == scales["regression"]
    assert main(["--ckpt", out, "--remove", "--physics", "learned"]) == 0
    assert "no std calibration of physics mode learned" in capsys.readouterr().out


def test_windows_that_open_their_trajectory_and_the_others_each_get_their_kinds_calibration(
        hybrid_ckpt, simulated_store, tmp_path, capsys):
    """A hybrid keeps a calibration per window kind: --offset random fits the one for windows that
    do not open their trajectory, kept beside the start windows'; a batch of both kinds gets each
    row's own factors, and where one kind is missing the other stands in; windows that all open
    their trajectory cannot fit the other kind's, and the checkpoint stays as it was."""
    from robomorph.calibrate import main
    from robomorph.inference.predictor import Predictor

    out = str(tmp_path / "kinds.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON + 40, seed=9)
    common = ["--data", heldout, "--n", "4", "--horizon", str(CKPT_HORIZON)]
    assert main(["--ckpt", hybrid_ckpt, "--out", out, *common]) == 0
    only_start = Predictor.from_checkpoint(out)
    assert main(["--ckpt", out, *common, "--offset", "random", "--seed", "1"]) == 0
    p = Predictor.from_checkpoint(out)
    assert set(p.model.calibrations) == {KEY, KEY + "/moving"}
    start, moving = p.model.calibrations[KEY], p.model.calibrations[KEY + "/moving"]
    assert start.scale != moving.scale and p.calibration is start
    uc, yc, uq, *_ = _windows(heldout, n=2)
    rest = np.array([True, False])
    with p.raw_std():
        _, raw = p.simulate(uc, yc, uq, return_std=True, at_rest=rest)
    _, std = p.simulate(uc, yc, uq, return_std=True, at_rest=rest)
    f = [start.factors(uq.shape[1]), moving.factors(uq.shape[1])]
    np.testing.assert_allclose(std, raw * np.stack(f), rtol=1e-5)
    _, alone = only_start.simulate(uc, yc, uq, return_std=True, at_rest=rest)
    np.testing.assert_allclose(alone, raw * start.factors(uq.shape[1])[None], rtol=1e-5)
    # Windows that fill their trajectory all open it: a "moving" calibration from them is refused.
    before = open(out, "rb").read()
    full = ["--data", heldout, "--n", "4", "--horizon", str(CKPT_HORIZON + 40), "--offset", "random"]
    assert main(["--ckpt", out, *full]) == 2
    assert "start after their trajectory's first step" in capsys.readouterr().err
    assert open(out, "rb").read() == before
    assert main(["--ckpt", out, "--remove", "--physics", "regression"]) == 0
    assert Predictor.from_checkpoint(out).model.calibrations == {}


def test_the_demo_calibrates_a_hybrid_for_start_windows_and_for_a_moving_robot(hybrid_ckpt, tmp_path, capsys,
                                                                              monkeypatch):
    """make demo's calibration step where no shipped calibration applies (tests/reproduction/test_demo.py has the
    one that does): the start windows' calibration, then the one for windows of a robot already moving (what a
    controller sends), both on the fit's validation robots."""
    import shutil

    from robomorph.inference import catalogue
    from robomorph.inference.predictor import Predictor
    from robomorph.reproduction.demo import calibrate_std

    monkeypatch.setattr(catalogue, "CALIBRATION_DIR", str(tmp_path / "none shipped"))

    ckpt = str(tmp_path / "best.ckpt")
    shutil.copy(hybrid_ckpt, ckpt)
    assert calibrate_std(ckpt) is True
    cals = Predictor.from_checkpoint(ckpt).model.calibrations
    assert set(cals) == {KEY, KEY + "/moving"}
    assert cals[KEY + "/moving"].source["offset"] == "random"
    out = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
    assert len(out) == 2  # one line each (the demo's brief; robomorph calibrate prints the table)
    assert "validation windows from the start" in out[0] and "validation windows from random offsets" in out[1]
