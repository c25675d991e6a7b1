"""Control on any registered arm: the world, the catalogue OSC, the planners and the model's arm all
come from the arms registry (real MuJoCo episodes, a few hundred frames each)."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from robomorph.control import dynamics as dyn
from robomorph.control.dynamics import ControlError
from robomorph.control.episode import CatalogueOSC, Episode
from robomorph.control.mppi import MPPIConfig
from robomorph.control.runner import ControlConfig, draw_episode, make_planner, model_arm, run_job
from robomorph.sim import arms

needs_robosuite = pytest.mark.skipif(importlib.util.find_spec("robosuite") is None,
                                     reason="robosuite (the `arms` extra) is not installed")
FAST = MPPIConfig(samples=48, horizon=12, knot=6)
# Arms of 7 and 6 joints, from two makers' models (dm-robotics' Panda, robosuite's UR5e and Gen3).
OTHER_ARMS = [pytest.param(name, marks=needs_robosuite) for name in ("ur5e", "kinova3")]


def _cfg(robot: str) -> ControlConfig:
    return ControlConfig(robot=robot, robots=1, warmup=0.5, duration=0.5, mpc=FAST, context=30, reidentify=15)


@pytest.mark.parametrize("robot", ["panda", *OTHER_ARMS])
def test_a_planner_with_the_worlds_parameters_predicts_the_worlds_record(robot):
    """At the world's physics step and with its hidden parameters, a physics planner's outputs are
    what the episode then measures, to rounding: the planner, the world and the layout of the
    outputs (EE pose, then the arm's own joints) are one arm's."""
    cfg = _cfg(robot)
    n = arms.get(robot).n_joint
    params, ref = draw_episode(cfg, 0)
    episode = Episode(params, ref, cfg.randomization(), cfg.dt, cfg.substeps, robot)
    episode.warm_up(CatalogueOSC(ref, episode.start, cfg.dt, cfg.substeps, robot=robot))
    assert episode.failure is None
    episode._measure()
    w, horizon = episode.frame, 10
    planner = dyn.TruePlanner("t", cfg.randomization(), cfg.dt, cfg.substeps, hidden=params, robot=robot)
    try:
        planner.observe(episode.m, first=True)
        # The warm-up's last command held, then a push on every joint: the arm moves.
        u = np.repeat(episode.m.u[w - 1][None], horizon, axis=0) + 0.02 * episode.limits
        predicted = planner.predict(u[None])[0]
    finally:
        planner.close()
    for k in range(horizon):
        episode._apply(u[k])
        episode._measure()
    world = episode.m.y[w + 1:w + 1 + horizon]
    assert predicted.shape == world.shape == (horizon, dyn.POSE + n)
    assert np.ptp(world[:, dyn.POSE:], axis=0).max() > 1e-4  # it did move
    np.testing.assert_allclose(predicted[:, :3], world[:, :3], atol=1e-12)
    np.testing.assert_allclose(predicted[:, dyn.POSE:], world[:, dyn.POSE:], atol=1e-12)
    # The quaternion's sign is kept continuous in the record only: compare orientations.
    np.testing.assert_allclose(np.abs(np.sum(predicted[:, 3:dyn.POSE] * world[:, 3:dyn.POSE], axis=1)), 1.0,
                               atol=1e-12)


@pytest.mark.parametrize("robot", OTHER_ARMS)
def test_mpc_tracks_on_other_arms_with_true_physics_and_the_arms_untrained_hybrid(robot):
    """The catalogue OSC, MPC on the true robot and MPC on the hybrid of the arm's catalogue
    (``Predictor.from_arm``, which identifies the robot from the rolling context) all finish the
    episode; both MPC controllers track within millimetres with commands inside the arm's limits."""
    from robomorph.inference.predictor import Predictor

    arm, cfg = arms.get(robot), _cfg(robot)
    predictor = Predictor.from_arm(robot)
    rms = {}
    for controller in ("osc", "mpc:true_physics", "mpc:model"):
        result = run_job(cfg, 0, controller, predictor)
        assert result.failure is None and result.frames == cfg.steps, (controller, result.failure)
        assert result.torque.shape == (cfg.steps, arm.n_joint)
        assert np.all(np.abs(result.torque) <= arm.limits + 1e-9)
        rms[controller] = float(np.sqrt(np.mean(result.error_mm ** 2)))
        if controller == "mpc:model":  # identified at the switch, then every 15 frames of the 30 tracked
            assert result.notes["identifications"] == 2
    assert rms["mpc:true_physics"] < 3.0 and rms["mpc:model"] < 5.0, rms


@needs_robosuite
def test_a_model_of_another_arm_or_an_unknown_arm_is_refused():
    from robomorph.inference.predictor import Predictor

    assert model_arm(Predictor.from_arm("ur5e")) == "ur5e"
    with pytest.raises(ControlError, match="is of the ur5e but the model was trained on the panda"):
        make_planner(_cfg("ur5e"), "mpc:model", np.zeros(0), Predictor.from_arm("panda"))
    with pytest.raises(ControlError, match="'nao' is not a registered arm: choose panda, ur5e"):
        ControlConfig(robot="nao")


@needs_robosuite
def test_the_control_command_runs_on_the_arm_it_is_given(tmp_path):
    from robomorph.cli import main

    out = tmp_path / "ctl"
    code = main(["control", "--robot", "ur5e", "--controllers", "osc,mpc:nominal_physics", "--robots", "1",
                 "--warmup", "0.5", "--duration", "0.3", "--candidates", "16", "--horizon", "8", "--workers", "1",
                 "--out", str(out)])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["_config"]["robot"] == "ur5e"
    for name in ("osc", "mpc:nominal_physics"):
        assert metrics[name]["episodes"] == 1 and metrics[name]["failed_episodes"] == 0
        assert np.isfinite(metrics[name]["ee_rms_mm"]) and metrics[name]["torque_rms_nm"] > 0
