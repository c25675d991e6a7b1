"""The arm registry: every arm compiles with the domain's construction, its filters fire, its
stores carry its names and re-simulate from their parameters, and the Panda is unchanged."""

import importlib.util
import os
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from robomorph.sim import arms, filters
from robomorph.sim.randomize import RandomizationConfig, Randomizer, param_names

ROBOSUITE_ARMS = [name for name in arms.names() if name != "panda"]
FIXTURE = os.path.join(os.path.dirname(__file__), "fixtures", "panda_before_arms.npz")
# The recipes of the fixture, written by the code before the registry existed (same function below).
FIXTURE_RUNS = (("multisine", "nominal_model"), ("chirp", "true_model"), ("circle", "true_model"),
                ("spiral", "true_model"))

HAVE_ROBOSUITE = importlib.util.find_spec("robosuite") is not None
needs_robosuite = pytest.mark.skipif(not HAVE_ROBOSUITE, reason="robosuite (the `arms` extra) is not installed")


def _require(name):
    if name != "panda" and not HAVE_ROBOSUITE:
        pytest.skip("robosuite (the `arms` extra) is not installed")


def _pose(model, data, q):
    data.qpos[:] = q
    data.qvel[:] = 0
    mujoco.mj_forward(model, data)
    return data.sensordata.copy()


@pytest.mark.parametrize("name", arms.names())
def test_every_arm_compiles_with_the_domain_layout(name):
    _require(name)
    arm = arms.get(name)
    m = arm.build_model()
    n = arm.n_joint
    assert m.nq == m.nv == m.nu == n in (6, 7)
    assert m.nsensordata == 8 + 3 * n and arms.SensorLayout.of_width(m.nsensordata) == arm.layout
    np.testing.assert_allclose(m.actuator_ctrlrange, np.stack([-arm.limits, arm.limits], axis=1))
    np.testing.assert_allclose(m.jnt_actfrcrange[:n], np.stack([-arm.limits, arm.limits], axis=1))
    assert m.geom("floor").id >= 0 and m.site("ee").id >= 0
    assert np.all(m.body_gravcomp[1:] == 1) and np.all(m.jnt_actgravcomp[:n] == 1)  # (body 0: the world)
    assert np.all(m.jnt_limited[:n]) and np.all(m.jnt_range[:n, 0] < m.jnt_range[:n, 1])
    off = arm.build_model(gravity_compensation=False)
    assert np.all(off.body_gravcomp == 0) and not np.any(off.jnt_actgravcomp)
    # The centre of the initial poses is free of contacts and away from the limits.
    sens = _pose(m, mujoco.MjData(m), arms.centre_pose(arm, m.jnt_range[:n]))
    assert sens[arm.layout.contacts] == 0
    assert arm.u_names == tuple(f"tau{i}" for i in range(n)) and len(arm.y_names) == 7 + n


@needs_robosuite
@pytest.mark.parametrize("name", ROBOSUITE_ARMS)
def test_torque_limits_are_robosuites(name):
    arm = arms.get(name)
    root = ET.parse(arms.robosuite_xml(arm.folder)).getroot()
    ranges = {mo.get("joint"): float(mo.get("ctrlrange").split()[1]) for mo in root.iter("motor")}
    assert [ranges[j] for j in arm.joint_names] == list(arm.torque_limits)


@pytest.mark.parametrize("name", ["panda"] + ROBOSUITE_ARMS)
def test_recorded_torque_is_gravity_at_rest(name):
    """With gravity compensation in the actuators and no command, the recorded joint torque
    is the bias force at rest (gravity alone) and the arm does not move."""
    _require(name)
    arm = arms.get(name)
    m = arm.build_model()
    d = mujoco.MjData(m)
    q = arms.centre_pose(arm, m.jnt_range[:arm.n_joint]) + 0.2
    sens = _pose(m, d, q)
    tau = sens[arm.layout.tau]
    assert np.abs(tau).max() > 0.5  # gravity does load the arm
    np.testing.assert_allclose(tau, d.qfrc_bias[:arm.n_joint], atol=1e-9)
    np.testing.assert_allclose(d.qacc, 0, atol=1e-6)  # (no spring: stiffness 0 at nominal)
    np.testing.assert_allclose(sens[arm.layout.cmd], 0, atol=1e-12)


def _floor_collision(arm, m, d):
    """A pose from the centre, the shoulder turned until some link touches the floor or itself."""
    centre = arms.centre_pose(arm, m.jnt_range[:arm.n_joint])
    lo, hi = m.jnt_range[1]
    for q1 in np.concatenate([np.linspace(centre[1], hi, 40), np.linspace(centre[1], lo, 40)]):
        q = centre.copy()
        q[1] = q1
        sens = _pose(m, d, q)
        if sens[arm.layout.contacts] > 0:
            return sens
    raise AssertionError(f"{arm.name}: no colliding pose found")


@pytest.mark.parametrize("name", ["panda", "ur5e", "kinova3", "jaco"])
def test_filters_fire_on_collision_and_joint_limit(name):
    _require(name)
    arm = arms.get(name)
    m = arm.build_model()
    d = mujoco.MjData(m)
    jr, cfg = m.jnt_range[:arm.n_joint], filters.FilterConfig()
    ok = _pose(m, d, arms.centre_pose(arm, jr))
    assert filters.check(np.stack([ok, ok]), jr, cfg, arm.limits) is None
    hit = _floor_collision(arm, m, d)
    assert filters.check(np.stack([ok, hit]), jr, cfg, arm.limits) == "contact"
    q = arms.centre_pose(arm, jr)
    q[-1] = jr[-1, 1] - 0.01  # the last joint turns the flange only: no contact on the way
    at_limit = _pose(m, d, q)
    assert at_limit[arm.layout.contacts] == 0
    assert filters.check(np.stack([ok, at_limit]), jr, cfg, arm.limits) == "joint_limit"
    over = ok.copy()
    over[arm.layout.tau.start + arm.n_joint - 1] = arm.limits[-1]
    assert filters.check(np.stack([ok, over]), jr, cfg, arm.limits) == "saturation"


@needs_robosuite
def test_randomizer_draws_around_each_arms_own_values():
    arm = arms.get("ur5e")
    m = arm.build_model()
    r = Randomizer(m, RandomizationConfig(), "ur5e")
    p = r.split(r.sample(np.random.default_rng(0)))
    assert len(r.sample(np.random.default_rng(1))) == len(param_names("ur5e")) == len(r.names)
    assert param_names("ur5e")[0] == "mass_shoulder_link" and param_names("ur5e")[-1] == "qinit_q5"
    assert np.all(np.abs(p["mass"] / r.mass0 - 1) <= 0.1)
    gain = arm.joint_gain
    assert np.all((p["damping"] >= 5 * gain) & (p["damping"] <= 10 * gain))
    lo, hi = m.jnt_range.T
    assert np.all((p["qinit"] > lo) & (p["qinit"] < hi))
    copy = arm.build_model()
    r.apply(copy, r.sample(np.random.default_rng(2)))
    assert not np.allclose(copy.body_mass, m.body_mass)


def _generate(tmp_path, robot, task, robots=2, steps=40, grav="true_model"):
    from robomorph.data.generation import generate
    from robomorph.data.store import open_store
    from robomorph.sim.recipe import load_recipe

    recipe = load_recipe(None, {"robot": robot, "task": task, "robots": robots, "steps": steps, "seed": 3,
                                "chunk": 2, "gravity_compensation": grav})
    path = str(tmp_path / f"{robot}_{task}.zarr")
    generate(recipe, path, workers=1, overwrite=True, progress=False)
    return open_store(path)


@needs_robosuite
@pytest.mark.parametrize("name,task", [("ur5e", "multisine"), ("kinova3", "chirp")])
def test_store_carries_the_arm_and_resimulates_from_its_params(tmp_path, name, task):
    from robomorph.evaluation.physics import NominalPhysics, check_params

    arm = arms.get(name)
    ds = _generate(tmp_path, name, task)
    a = ds.attrs
    assert a["domain"] == name and a["config"]["robot"] == name and a["joint_names"] == list(arm.joint_names)
    assert ds.u_names == list(arm.u_names) and ds.y_names == list(arm.y_names)
    assert ds.param_names == param_names(name)
    y, u_cmd, params = ds.read("y"), ds.read("u_cmd"), ds.read("params")
    assert y.shape == (2, 40, 7 + arm.n_joint) and u_cmd.shape == (2, 40, arm.n_joint)
    check_params(a)
    sim = NominalPhysics(a, inputs="command")
    q = y[0, :, 7:].astype(np.float64)
    again = sim.rollout(u_cmd[0], q[0], np.zeros(arm.n_joint), params[0].astype(np.float64))
    # float32 storage of the parameters and commands is all that differs
    np.testing.assert_allclose(again[:, 7:], q, atol=2e-3)
    np.testing.assert_allclose(again[:, :3], y[0, :, :3], atol=2e-3)
    # the catalogue robot predicts the same windows with the right shapes
    pred = sim(u_cmd[:, :20], y[:, :20], u_cmd[:, 20:])
    assert pred.shape == (2, 20, 7 + arm.n_joint) and np.all(np.isfinite(pred))


@needs_robosuite
@pytest.mark.slow
@pytest.mark.parametrize("task", ["circle", "spiral"])
def test_osc_tasks_run_on_a_six_joint_arm(tmp_path, task):
    ds = _generate(tmp_path, "ur5e", task, steps=120)
    target, y = ds.read("target"), ds.read("y")
    err = np.linalg.norm(y[:, 60:, :3] - target[:, 60:], axis=-1)
    assert err.max() < 0.05  # the flange tracks its path within centimetres


def _panda_fixture_arrays(tmp_path) -> dict:
    """The arrays of FIXTURE_RUNS (how the fixture was made, with the code before the registry)."""
    out = {}
    for task, grav in FIXTURE_RUNS:
        ds = _generate(tmp_path, "panda", task, robots=2, steps=30, grav=grav)
        for name in ("u", "u_cmd", "y", "params", "attempt"):
            out[f"{task}/{name}"] = ds.read(name)
    return out


def test_panda_stores_are_unchanged_by_the_registry(tmp_path):
    before = np.load(FIXTURE)
    now = _panda_fixture_arrays(tmp_path)
    assert sorted(before.files) == sorted(now)
    for key in before.files:
        np.testing.assert_allclose(now[key], before[key], rtol=0, atol=1e-6, err_msg=key)


def test_recipe_robot_field(tmp_path):
    from robomorph.core.config import ConfigError
    from robomorph.generate import build_parser
    from robomorph.sim.recipe import Recipe, load_recipe

    assert Recipe().robot == "panda" and "robot" not in Recipe().to_dict()  # Panda recipes unchanged
    assert load_recipe(None, {"robot": "ur5e"}).to_dict()["robot"] == "ur5e"
    with pytest.raises((ValueError, ConfigError), match="unknown robot"):
        load_recipe(None, {"robot": "r2d2"})
    assert build_parser().parse_args(["--robot", "ur5e", "--out", "x"]).robot == "ur5e"
    with pytest.raises(arms.UnknownRobotError, match="choose from"):
        arms.get("r2d2")


def test_mixture_recipe_over_arms_loads():
    from robomorph.sim.recipe import load_recipe

    for robot in ROBOSUITE_ARMS:
        assert load_recipe("arms", {"robot": robot}).robot == robot


@needs_robosuite
@pytest.mark.parametrize("name", ["ur5e", "kinova3"])
def test_identified_physics_recovers_another_arms_damping_and_beats_its_catalogue(simulated_store, name):
    """identified_physics fits any registered arm: robots of the arm that differ from its
    catalogue only in their damping (ranges scaled per joint as the randomizer scales them) get
    their damping back, and the fitted robot predicts the horizon better than the catalogue."""
    from robomorph.data.store import open_store
    from robomorph.evaluation.identified import IdentifiedPhysics
    from robomorph.evaluation.physics import NominalPhysics

    only_damping = {"mass_pct": 0.0, "com_offset": 0.0, "damping": [5.0, 10.0], "stiffness": [0.03, 0.03],
                    "armature": [0.1, 0.1], "frictionloss_scale": [1.0, 1.0]}
    ds = open_store(simulated_store(robots=2, steps=120, seed=3, robot=name, randomization=only_damping))
    nj, c = arms.get(name).n_joint, 60
    y, u, params = ds.read("y").astype(np.float64), ds.read("u_cmd").astype(np.float64), ds.read("params")
    with IdentifiedPhysics(ds.attrs, "command") as ident:
        pred = ident(u[:, :c], y[:, :c], u[:, c:], at_rest=np.ones(2, dtype=bool))
        space = ident.identifier.space
        assert space.names == tuple(f"damping_q{j}" for j in range(nj))  # nothing else can differ
        catalogue_values = ident.physics.params(y[0, 0, 7:])[space.index]
        for b, fit in enumerate(ident.fits):
            truth = params[b, space.index]
            assert np.all((truth >= space.low) & (truth <= space.high))  # the bounds hold the arm's draws
            assert np.abs(fit.values - truth).mean() < 0.1 * np.abs(catalogue_values - truth).mean()
    nominal = NominalPhysics(ds.attrs, "command")(u[:, :c], y[:, :c], u[:, c:])
    assert pred.shape == nominal.shape == (2, 60, 7 + nj)
    err_fit = np.sqrt(np.mean((pred[..., 7:] - y[:, c:, 7:]) ** 2))
    err_cat = np.sqrt(np.mean((nominal[..., 7:] - y[:, c:, 7:]) ** 2))
    assert err_fit < 0.2 * err_cat


@needs_robosuite
def test_the_hybrid_identifies_and_simulates_every_arm_with_no_training(tmp_path):
    """The hybrid's backbone is any registered arm's: with no training (Predictor.from_arm) it
    predicts a simulated Kinova far below the catalogue arm; a store of no arm is refused in one line."""
    from robomorph import Predictor
    from robomorph.evaluation.physics import NominalPhysics
    from robomorph.identification.backbone import BackboneError, parameter_layout

    ds = _generate(tmp_path, "kinova3", "multisine", robots=2, steps=260)
    layout = parameter_layout(ds.attrs)
    assert any(n.startswith("mass_HalfArm1") for n in layout["names"])
    y, u = ds.read("y").astype(np.float64), ds.read("u_cmd").astype(np.float64)
    c = 200
    pred = Predictor.from_arm("kinova3").simulate(u[:, :c], y[:, :c], u[:, c:], at_rest=True)
    nominal = NominalPhysics(ds.attrs, "command")(u[:, :c], y[:, :c], u[:, c:])
    assert pred.shape == nominal.shape == (2, 60, 14)
    err = np.sqrt(np.mean((pred[..., 7:] - y[:, c:, 7:]) ** 2))
    assert err < 0.2 * np.sqrt(np.mean((nominal[..., 7:] - y[:, c:, 7:]) ** 2))
    # An arm compensating its gravity with the catalogue model takes its commands, undebiased (measured worse).
    assert Predictor.from_arm("kinova3").settings_in_effect.debias
    assert not Predictor.from_arm("kinova3", gravity_compensation="nominal_model").settings_in_effect.debias
    with pytest.raises(BackboneError, match="simulated stores of a registered arm") as info:
        parameter_layout({**ds.attrs, "domain": "real"})
    assert "\n" not in str(info.value)


@needs_robosuite
@pytest.mark.parametrize("name", ROBOSUITE_ARMS)
def test_the_lean_model_of_every_arm_has_its_dynamics(name):
    """The fits' lean model (no meshes, sensors or contacts) keeps the arm's inertias, joints and
    motors, so a contact-free motion is the same in both (to rounding)."""
    from robomorph.identification.identify import lean_model

    full = arms.get(name).build_model(8, 1 / 60, True)
    lean = lean_model(8, 1 / 60, True, name)
    assert lean.nmesh == 0 and lean.nsensor == 0 and lean.nu == full.nu == arms.get(name).n_joint
    moving = full.body_weldid != 0  # a base welded to the world may lose its mesh-derived mass: it never moves
    for field in ("body_mass", "body_inertia", "body_ipos"):
        np.testing.assert_array_equal(getattr(lean, field)[moving], getattr(full, field)[moving])
    for field in ("dof_damping", "dof_armature", "dof_frictionloss", "jnt_range", "actuator_ctrlrange"):
        np.testing.assert_array_equal(getattr(lean, field), getattr(full, field))
    qpos = []
    for model in (full, lean):
        model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT  # the lean model has none
        data = mujoco.MjData(model)
        data.qpos[:] = arms.centre_pose(arms.get(name), model.jnt_range)
        data.ctrl[:] = 0.05 * arms.get(name).limits
        mujoco.mj_step(model, data, nstep=80)
        qpos.append(data.qpos.copy())
    np.testing.assert_allclose(qpos[1], qpos[0], rtol=0, atol=1e-12)  # the base's mass only reorders sums
