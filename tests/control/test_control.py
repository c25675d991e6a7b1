"""Closed-loop control: MPPI on physics and on the in-context model, in real MuJoCo episodes."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import numpy as np
import pytest

from robomorph.control import dynamics as dyn
from robomorph.control.episode import CatalogueOSC, Episode
from robomorph.control.mppi import MPPI, Goal, MPPIConfig, tracking_cost
from robomorph.control.references import draw_reference
from robomorph.control.runner import ControlConfig, draw_episode, make_planner, run_job
from robomorph.sim.randomize import RandomizationConfig
from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON, tiny_fit_args

FAST = MPPIConfig(samples=48, horizon=12, knot=6)
SHORT = ControlConfig(robots=1, warmup=0.5, duration=0.5, mpc=FAST, context=CKPT_CONTEXT)


@pytest.fixture(scope="module")
def hybrid_ckpt(simulated_store, tmp_path_factory) -> str:
    from robomorph.training.fitting import fit

    store = simulated_store(robots=24, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=3)
    args = tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "hybrid", steps=6,
                         data={"inputs": "command"}, model={"physics": "amortized", "anchor": True})
    return fit(args).best_ckpt


def _nominal_episode(duration: float = 1.0, seed: int = 0):
    """The catalogue robot at its home pose on a 10 cm circle (reachable), warm-up 0.5 s."""
    from robomorph.sim import panda
    from robomorph.sim.randomize import Randomizer

    model = panda.build_model()
    r = Randomizer(model, RandomizationConfig())
    ep_params = r.catalogue(panda.HOME_QPOS)  # springs anchored (qinit) at the home pose
    import mujoco

    from robomorph.sim.osc import start_pose
    r.apply(model, ep_params)
    pos, quat = start_pose(model, mujoco.MjData(model), panda.HOME_QPOS)
    ref = draw_reference("circle", np.random.default_rng(seed), pos, quat, 30, 30 + int(duration * 60), 1 / 60)
    return Episode(ep_params, ref, RandomizationConfig()), ep_params


def _track(episode: Episode, planner, cfg: MPPIConfig = FAST, seed: int = 0):
    osc = CatalogueOSC(episode.ref, episode.start, episode.dt, episode.substeps)
    episode.warm_up(osc)
    mppi = MPPI(cfg, episode.limits, np.random.default_rng(seed))
    try:
        return episode.track("mpc", osc, planner, mppi)
    finally:
        planner.close()


def test_mppi_candidates_keep_the_plan_first_and_respect_the_limits():
    limits = np.array([87.0] * 4 + [12.0] * 3)
    mppi = MPPI(MPPIConfig(samples=16, horizon=8, knot=4, noise=0.5), limits, np.random.default_rng(0))
    mppi.reset(np.array([80.0, 0, 0, 0, 11.5, 0, 0]))
    cand, eps = mppi.candidates()
    assert cand.shape == eps.shape == (16, 8, 7)
    np.testing.assert_array_equal(cand[0], mppi.plan_)
    assert np.all(np.abs(cand) <= limits + 1e-12) and np.any(np.abs(cand[1:]) == limits)
    # Smooth exploration (away from the limits): knots every 4 frames, straight lines between them.
    small = MPPI(MPPIConfig(samples=16, horizon=8, knot=4, noise=0.01), limits, np.random.default_rng(0))
    eps = small.candidates()[1]
    np.testing.assert_allclose(eps[1:, 1] - eps[1:, 0], eps[1:, 2] - eps[1:, 1], atol=1e-9)
    assert not np.allclose(eps[1:, 5] - eps[1:, 4], eps[1:, 1] - eps[1:, 0])  # the next segment


def test_tracking_cost_is_lowest_for_the_reference():
    goal = Goal(pos=np.zeros((5, 3)), quat=np.array([0, 0, 0, 1.0]), q_now=np.zeros(7), posture=np.zeros(7),
                dt=1 / 60, joint_range=np.tile([-2.0, 2.0], (7, 1)))
    y = np.zeros((3, 5, 14))
    y[:, :, 6] = 1.0
    y[1, :, 0] = 0.01  # 1 cm off
    y[2, :, 7] = 1.95  # a joint inside the limit band
    cost = tracking_cost(y, goal, MPPIConfig())
    assert cost[0] == 0.0 and cost[1] > 0 and cost[2] > cost[1]


def test_reach_moves_then_holds_and_circles_follow_the_generator():
    from robomorph.sim.paths import PATHS, CircleConfig

    start = np.array([0.4, 0.0, 0.5])
    ref = draw_reference("reach", np.random.default_rng(1), start, np.array([1.0, 0, 0, 0]), 60, 300, 1 / 60)
    step = np.linalg.norm(ref.pos[-1] - ref.pos[60])
    assert 0.1 <= step <= 0.2 + 1e-9
    np.testing.assert_allclose(ref.pos[-100:], ref.pos[-1:].repeat(100, 0))  # held after the 1.5 s move
    np.testing.assert_allclose(ref.vel[-100:], 0.0)
    circle = draw_reference("circle", np.random.default_rng(2), start, np.array([1.0, 0, 0, 0]), 60, 300, 1 / 60)
    np.testing.assert_allclose(circle.pos, PATHS["circle"](np.random.default_rng(2), start, 300, 1 / 60,
                                                           CircleConfig())[0])
    with pytest.raises(ValueError, match="warm-up"):
        draw_reference("circle", np.random.default_rng(0), start, np.array([1.0, 0, 0, 0]), 300, 300, 1 / 60)


def test_references_out_of_reach_are_told_apart():
    import mujoco

    from robomorph.control.references import Reference, reachable
    from robomorph.sim import panda
    from robomorph.sim.osc import start_pose

    model = panda.build_model()
    pos, quat = start_pose(model, mujoco.MjData(model), panda.HOME_QPOS)
    t = np.arange(120)[:, None] / 120
    near = Reference(pos + 0.05 * t * [0, 1, 0], np.zeros((120, 3)), np.zeros((120, 3)), quat, 10)
    far = Reference(pos + 1.0 * t * [1, 0, 0], np.zeros((120, 3)), np.zeros((120, 3)), quat, 10)  # a metre away
    assert reachable(model, near, panda.HOME_QPOS)
    assert not reachable(model, far, panda.HOME_QPOS)


def test_true_physics_mpc_tracks_within_millimetres_and_a_wrong_model_does_worse():
    episode, params = _nominal_episode()
    true = dyn.TruePlanner("true", RandomizationConfig(), 1 / 60, 2, hidden=params)
    good = _track(episode, true)
    assert good.failure is None
    good_rms = float(np.sqrt(np.mean(good.error_mm ** 2)))
    assert good_rms < 3.0, good_rms
    wrong_params = params.copy()
    split = true.randomizer.split(wrong_params)  # views into wrong_params
    split["mass"] *= 1.6
    split["damping"] *= 0.1
    split["frictionloss"] *= 4.0
    wrong = dyn.TruePlanner("wrong", RandomizationConfig(), 1 / 60, 2, hidden=wrong_params)
    bad = _track(_nominal_episode()[0], wrong)
    bad_rms = float(np.sqrt(np.mean(bad.error_mm ** 2)))
    assert bad_rms > 1.5 * good_rms, (good_rms, bad_rms)


def _first_plan(cfg: ControlConfig, controller: str, hidden_change: bool, predictor=None) -> np.ndarray:
    params, ref = draw_episode(cfg, 0)
    episode = Episode(params, ref, cfg.randomization())
    episode.warm_up(CatalogueOSC(ref, episode.start, episode.dt, episode.substeps))
    planner = make_planner(cfg, controller, params, predictor)
    if hidden_change:
        changed = params.copy()
        split = episode.randomizer.split(changed)
        split["damping"] *= 1.5
        split["mass"] *= 0.8
        episode.set_hidden(changed)
        if isinstance(planner, dyn.TruePlanner):
            planner.hidden = changed  # the ceiling is handed the world's parameters, as run_job hands them
    mppi = MPPI(cfg.mpc, episode.limits, np.random.default_rng(5))
    mppi.reset(episode.m.u[episode.frame - 1])
    episode._measure()
    try:
        return episode.plan(planner, mppi, first=True)
    finally:
        planner.close()


def test_only_true_physics_reads_the_hidden_parameters(hybrid_ckpt):
    """The world's parameters change after the warm-up: the measurements so far are the same, so
    every controller but the ceiling makes the same first plan."""
    from robomorph.inference.predictor import Predictor

    cfg = dataclasses.replace(SHORT, context=CKPT_CONTEXT)
    hybrid = Predictor.from_checkpoint(hybrid_ckpt)
    black_box = Predictor.from_checkpoint(hybrid_ckpt)
    black_box.configure(mode="none")
    for controller, predictor in (("mpc:nominal_physics", None), ("mpc:model", hybrid), ("mpc:model", black_box)):
        np.testing.assert_array_equal(_first_plan(cfg, controller, False, predictor),
                                      _first_plan(cfg, controller, True, predictor), err_msg=controller)
    assert not np.array_equal(_first_plan(cfg, "mpc:true_physics", False),
                              _first_plan(cfg, "mpc:true_physics", True))


def test_episodes_are_deterministic_under_a_seed():
    a = run_job(SHORT, 0, "mpc:nominal_physics")
    b = run_job(SHORT, 0, "mpc:nominal_physics")
    np.testing.assert_array_equal(a.ee, b.ee)
    np.testing.assert_array_equal(a.torque, b.torque)
    c = run_job(dataclasses.replace(SHORT, seed=1), 0, "mpc:nominal_physics")
    assert not np.array_equal(a.ee, c.ee)


def _control(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "robomorph", "control", *args], capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def control_out(hybrid_ckpt, tmp_path_factory):
    out = tmp_path_factory.mktemp("control") / "ctl"
    res = _control("--ckpt", hybrid_ckpt, "--robots", "1", "--warmup", "0.5", "--duration", "0.3",
                   "--context-len", str(CKPT_CONTEXT), "--candidates", "32", "--horizon", "10", "--workers", "2",
                   "--controllers", "osc,mpc:model,mpc:nominal_physics,mpc:true_physics", "--out", str(out))
    assert res.returncode == 0, res.stderr[-2000:]
    return out


def test_control_command_writes_metrics_table_and_plots(control_out):
    out = control_out
    metrics = json.loads((out / "metrics.json").read_text())
    for name in ("osc", "mpc:model", "mpc:nominal_physics", "mpc:true_physics"):
        assert metrics[name]["episodes"] == 1 and np.isfinite(metrics[name]["ee_rms_mm"])
    assert metrics["mpc:true_physics"]["reads_hidden_parameters"] and not metrics["mpc:model"]["reads_hidden_parameters"]
    assert metrics["mpc:model"]["replan_ms_median"] > 0 and metrics["osc"]["replan_ms_median"] is None
    assert "commit" in metrics["_provenance"] and "EE RMS [mm]" in (out / "table.md").read_text()
    assert (out / "errors.png").stat().st_size > 0 and (out / "paths.png").stat().st_size > 0


def test_the_dashboard_shows_the_control_section(control_out, tiny_checkpoint, tmp_path):
    from pathlib import Path

    from robomorph.reporting.dashboard import build_report

    runs_dir = Path(tiny_checkpoint).parents[2]  # <runs>/<run>/checkpoints/best.ckpt
    page = Path(build_report(str(runs_dir), str(tmp_path / "r.html"), control=str(control_out))).read_text()
    assert "Closed-loop control" in page and "mpc:true_physics (ceiling" in page and "mpc:nominal_physics" in page
    assert page.count("data:image/png;base64") >= 2
    plain = Path(build_report(str(runs_dir), str(tmp_path / "r2.html"), control=str(tmp_path))).read_text()
    assert "Closed-loop control" not in plain  # a folder without metrics.json adds nothing


def test_bad_options_get_one_line_and_exit_code_2(hybrid_ckpt, tiny_checkpoint, tmp_path, capsys, monkeypatch):
    cases = [
        (["--controllers", "osc,mpc:magic"], "unknown 'mpc:magic'"),
        (["--controllers", "mpc:model"], "needs --ckpt"),
        (["--ckpt", hybrid_ckpt, "--controllers", "mpc:model", "--context-len", str(CKPT_CONTEXT), "--horizon", "500"],
         "beyond the model's trained maximum"),
        (["--ckpt", tiny_checkpoint, "--controllers", "mpc:model", "--context-len", str(CKPT_CONTEXT)],
         "trained on total torques"),
        (["--ckpt", hybrid_ckpt, "--robot", "ur5e", "--controllers", "mpc:model", "--context-len", str(CKPT_CONTEXT)],
         "the controlled arm is of the ur5e but the model was trained on the panda"),
        (["--ckpt", str(tmp_path / "missing.ckpt"), "--controllers", "mpc:model"], "missing.ckpt"),
        (["--robots", "0"], "argument --robots: takes a whole number >= 1"),
    ]
    from robomorph.cli import main

    monkeypatch.setattr(sys, "argv", list(sys.argv))  # robomorph.cli.main sets it for the door it runs
    for i, (args, expected) in enumerate(cases):
        if i == 0:  # one in a process of its own, what a shell sees; the others in this one (imports once)
            res = _control(*args, "--out", str(tmp_path / "x"))
            code, err = res.returncode, res.stderr
        else:
            try:
                code = main(["control", *args, "--out", str(tmp_path / "x")])
            except SystemExit as stop:  # argparse's own refusals exit from inside the parser
                code = stop.code
            err = capsys.readouterr().err
        assert code == 2, (args, err[-1500:])
        lines = [line for line in err.strip().splitlines() if line.strip()]
        assert len(lines) == 1 and expected in lines[0], (args, err)
    assert not (tmp_path / "x").exists()


def test_workers_start_with_ctrl_c_ignored_and_the_parent_keeps_its_handler():
    """A Ctrl-C stops a run in the parent; a worker ignores it from its first instruction, so one that
    arrives while the worker still imports prints no traceback (a spawned interpreter keeps an ignored
    SIGINT ignored). Negative control: a worker started outside the block has Python's handler."""
    import multiprocessing as mp
    import signal
    from concurrent.futures import ProcessPoolExecutor

    from robomorph.control.cli import _interrupts_ignored

    before = signal.getsignal(signal.SIGINT)
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        with _interrupts_ignored():
            ignored = pool.submit(signal.getsignal, signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) is before
        assert ignored.result(timeout=120) == signal.SIG_IGN
    with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
        assert pool.submit(signal.getsignal, signal.SIGINT).result(timeout=120) == signal.default_int_handler
