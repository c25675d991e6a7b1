"""Realism terms of the recipe: each term's effect on the simulated log, with real MuJoCo."""

import mujoco
import numpy as np
import pytest

from robomorph.core.config import ConfigError
from robomorph.sim import arms, episode, kinematics, realism, realistic
from robomorph.sim.closed_loop import simulate_substeps
from robomorph.sim.randomize import RandomizationConfig, Randomizer
from robomorph.sim.recipe import load_recipe

# A robot with nothing randomized that acts at rest (no damping, springs or dry friction), so
# that the payload's and the controller's effects are the only motion.
STILL = {"mass_pct": 0.0, "com_offset": 0.0, "damping": [0.0, 0.0], "stiffness": [0.0, 0.0],
         "armature": [0.1, 0.1], "frictionloss_scale": [0.0, 0.0]}
QUIET = {"chirp_amplitude": 0.0, "chirp_offset": 0.0}  # a chirp of zero torque


def recipe(**over):
    return load_recipe(None, {"steps": 60, "robots": 4, **over})


def outcome(r, index=0):
    return episode.ClosedLoopRunner(r)(index)


def test_a_clean_recipe_records_no_realism_and_draws_as_before():
    clean = recipe()
    assert "realism" not in clean.to_dict() and not clean.realism.enabled
    noisy = recipe(realism={"encoder": {"noise": [1e-4, 1e-4]}, "torque": {"offset": 0.01}})
    assert noisy.to_dict()["realism"]["encoder"]["noise"] == [1e-4, 1e-4]
    rand = Randomizer(episode.build_model(clean), clean.randomization)
    a, b = episode.draw(clean, rand, 3), episode.draw(noisy, rand, 3)
    # The realism draws come from a stream of their own: robot and signal do not move.
    np.testing.assert_array_equal(a.params, b.params)
    np.testing.assert_array_equal(a.ctrl, b.ctrl)
    assert a.real is None and b.real is not None
    # Sensor errors only: the fast open-loop engine still runs it.
    assert episode.is_open_loop(noisy, "multisine") and not noisy.realism.steps_in_python


def test_encoder_noise_has_the_drawn_std_and_the_pose_follows_the_noisy_joints():
    clean = outcome(recipe(steps=300, task="chirp"))
    r = recipe(steps=300, task="chirp", realism={"encoder": {"noise": [2e-5, 8e-5]}})
    noisy = outcome(r)
    drawn = noisy.realism[realism.names(7).index("encoder_noise")]
    err = noisy.y[:, 7:].astype(np.float64) - clean.y[:, 7:]
    assert 2e-5 <= drawn <= 8e-5
    assert np.std(err) == pytest.approx(drawn, rel=0.1)
    np.testing.assert_array_equal(noisy.u, clean.u)  # the torque sensor is untouched
    pose = kinematics.ee_pose(noisy.y[:, 7:].astype(np.float64), episode.build_model(r))
    np.testing.assert_allclose(noisy.y[:, :7], pose, atol=1e-6)
    assert np.abs(noisy.y[:, :3] - clean.y[:, :3]).max() > 1e-6  # the pose did move with the joints


def test_encoder_quantization_puts_the_joints_on_the_drawn_grid():
    out = outcome(recipe(task="chirp", realism={"encoder": {"resolution": [1e-4, 2e-4]}}))
    res = out.realism[realism.names(7).index("encoder_resolution")]
    counts = out.y[:, 7:].astype(np.float64) / res
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-2)  # float32 rounding of q ~ 3 rad


def test_the_logged_torque_carries_the_drawn_offset_and_scale_and_the_command_stays_exact():
    clean = outcome(recipe(task="chirp"))
    names = realism.names(7)
    off = outcome(recipe(task="chirp", realism={"torque": {"offset": 0.02}}))
    drawn = off.realism[[names.index(f"torque_offset_q{j}") for j in range(7)]]
    assert np.all(np.abs(drawn) > 0) and np.all(np.abs(drawn) <= 0.02 * recipe().arm.limits)
    np.testing.assert_allclose(off.u - clean.u, np.broadcast_to(drawn, clean.u.shape), atol=1e-4)
    np.testing.assert_array_equal(off.u_cmd, clean.u_cmd)
    scaled = outcome(recipe(task="chirp", realism={"torque": {"scale": 0.05}}))
    scale = scaled.realism[[names.index(f"torque_scale_q{j}") for j in range(7)]]
    np.testing.assert_allclose(scaled.u, clean.u * scale, rtol=1e-5, atol=1e-5)
    assert np.abs(scale - 1).max() > 0.005


def test_torque_noise_has_the_drawn_std_per_joint():
    clean = outcome(recipe(steps=400, task="chirp"))
    noisy = outcome(recipe(steps=400, task="chirp", realism={"torque": {"noise": [0.001, 0.003]}}))
    names = realism.names(7)
    drawn = noisy.realism[[names.index(f"torque_noise_q{j}") for j in range(7)]]
    np.testing.assert_allclose(drawn / recipe().arm.limits, drawn[0] / recipe().arm.limits[0], rtol=1e-5)
    np.testing.assert_allclose(np.std(noisy.u.astype(np.float64) - clean.u, axis=0), drawn, rtol=0.15)


def test_latency_delays_the_motion_by_the_drawn_steps():
    r = recipe(task="chirp")
    model = episode.build_model(r)
    data = mujoco.MjData(model)
    q0 = arms.centre_pose(r.arm, model.jnt_range[:7])
    Randomizer(model, r.randomization).apply(model, Randomizer(model, r.randomization).catalogue(q0))  # springs at q0
    push = np.array([2.0, 1.0, 0, 0, 0, 0, 0.5])  # the arm's own gravcomp holds it at rest before
    runs = {lat: simulate_substeps(model, data, q0, 10, 8, lambda d, k: push, latency=lat) for lat in (0, 3)}
    lay = r.arm.layout
    sens0, sens3 = runs[0][0], runs[3][0]
    np.testing.assert_array_equal(runs[3][1], runs[0][1])  # what was sent is the same
    # The motors' force: nothing for 3 physics steps, then the push.
    np.testing.assert_allclose(sens3[:3, lay.cmd], 0.0)
    np.testing.assert_allclose(sens3[3:, lay.cmd], np.broadcast_to(push, (77, 7)))
    # The motion is the undelayed one, 3 steps later.
    np.testing.assert_allclose(sens3[3:, lay.qpos], sens0[:-3, lay.qpos], atol=1e-9)
    assert np.abs(sens0[20, lay.qpos] - sens3[20, lay.qpos]).max() > 1e-7


def test_the_drawn_latency_delays_a_recipes_commands_and_the_log_keeps_what_was_sent():
    r = recipe(task="chirp", gravity_compensation="true_model", realism={"timing": {"latency": [2, 5]}})
    runner = episode.ClosedLoopRunner(r)
    d = episode.draw(r, runner.randomizer, 0)
    runner.randomizer.apply(runner.model, d.params)
    res = realistic.simulate(r, runner.model, runner.data, d, d.real, None)
    lat, cmd = d.real.latency, res.sens[:, r.arm.layout.cmd]
    assert 2 <= lat <= 5 and runner(0).realism[realism.names(7).index("latency")] == lat
    np.testing.assert_allclose(cmd[lat:], res.command[:-lat], atol=1e-12)  # the motors act lat steps late
    np.testing.assert_allclose(cmd[:lat], 0.0)
    np.testing.assert_array_equal(res.command[::r.substeps], np.clip(d.ctrl, -r.arm.limits, r.arm.limits))


def test_friction_opposes_motion_with_a_stribeck_peak_and_per_direction_levels():
    real = realism.draw(realism.RealismConfig(friction=realism.FrictionConfig(
        coulomb=(0.5, 0.5), viscous=(0.1, 0.1), stribeck_ratio=(1.5, 1.5), stribeck_velocity=(0.1, 0.1),
        asymmetry=0.3)), np.random.default_rng(0), np.ones(2), np.ones(2), 0.2, False)
    f = lambda v: realism.friction_torque(real, np.array([v, v]), 0.01)  # noqa: E731
    fast = 2.0
    for j in range(2):
        assert f(fast)[j] == pytest.approx(-(real.coulomb[0, j] + real.viscous[0, j] * fast), rel=1e-6)
        assert f(-fast)[j] == pytest.approx(real.coulomb[1, j] + real.viscous[1, j] * fast, rel=1e-6)
    assert np.all(f(0.3) < 0) and np.all(f(-0.3) > 0) and np.all(f(0.0) == 0)
    assert not np.allclose(-f(fast), f(-fast))  # asymmetric
    # Breakaway above Coulomb at low speed (the Stribeck hump), Coulomb at high speed.
    assert np.all(-f(0.05) > real.coulomb[0] + 0.05 * real.viscous[0])


def test_friction_slows_a_driven_joint_in_simulation():
    r = recipe(task="chirp", gravity_compensation="true_model")
    model, real = episode.build_model(r), None
    data = mujoco.MjData(model)
    cfg = realism.RealismConfig(friction=realism.FrictionConfig(coulomb=(2.0, 2.0)))
    real = realism.draw(cfg, np.random.default_rng(1), r.arm.limits, r.arm.joint_gain, 0.2, False)
    q0 = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0])
    push = lambda d, k: np.full(7, 3.0)  # noqa: E731
    free, _ = simulate_substeps(model, data, q0, 20, 8, push)
    slowed, _ = simulate_substeps(model, data, q0, 20, 8, push,
                                  passive=lambda v: realism.friction_torque(real, v, 0.1))
    q = r.arm.layout.qpos
    assert np.all(np.abs(slowed[-1, q] - q0) < np.abs(free[-1, q] - q0))


def test_the_payload_adds_its_mass_and_centre_and_never_compounds():
    model = episode.build_model(recipe())
    flange = realistic.Flange(model)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    mass0 = model.body_mass.sum()
    for _ in range(2):
        flange.apply(model, 1.5, np.array([0.0, 0.02, 0.05]))
    mujoco.mj_forward(model, data)
    assert model.body_mass.sum() == pytest.approx(mass0 + 1.5)
    b = flange.body
    xpos = data.xpos[b] + data.xmat[b].reshape(3, 3) @ np.array([0.0, 0.02, 0.05])
    com_flange = data.xipos[b]
    m_body = flange.nominal[0]
    expect = (m_body * (data.xpos[b] + data.xmat[b].reshape(3, 3) @ flange.nominal[1]) + 1.5 * xpos) / (m_body + 1.5)
    np.testing.assert_allclose(com_flange, expect, atol=1e-9)
    flange.apply(model, 0.0, np.zeros(3))
    assert model.body_mass[b] == flange.nominal[0]


def test_the_compensation_is_gravity_with_the_configured_payload():
    r = recipe(gravity_compensation="nominal_model")
    comp = realistic.Compensation(r.arm, r.substeps, r.dt)
    q = np.array([0.3, -0.4, 0.2, -2.0, 0.1, 1.8, 0.5])
    d = mujoco.MjData(comp.model)
    d.qpos[:] = q
    mujoco.mj_forward(comp.model, d)
    np.testing.assert_allclose(comp(q), d.qfrc_bias, atol=1e-10)
    bare = comp(q)
    comp.configure(1.0, np.zeros(3))
    jac = np.zeros((3, 7))
    b = comp.flange.body
    mujoco.mj_forward(comp.model, d)
    mujoco.mj_jac(comp.model, d, jac, None, d.xpos[b], b)
    # A 1 kg point mass at the flange origin weighs J^T (0, 0, 9.81).
    np.testing.assert_allclose(comp(q) - bare, jac.T @ np.array([0, 0, 9.81]), atol=1e-6)


@pytest.mark.parametrize("configured", [1.0, 0.0])
def test_nominal_compensation_leaves_an_unconfigured_payload_in_the_motion(configured):
    r = recipe(task="chirp", steps=20, gravity_compensation="nominal_model", randomization=STILL, signal=QUIET,
               realism={"payload": {"mass": [1.0, 1.0], "com": 0.0, "configured": configured}})
    out = outcome(r)
    assert out.reason is None
    q = out.y[:, 7:].astype(np.float64)
    drift = np.abs(q - q[0]).max()
    names = realism.names(7)
    assert out.realism[names.index("payload_mass")] == 1.0
    assert out.realism[names.index("payload_configured")] == configured
    if configured:
        assert drift < 1e-6  # the controller holds the payload it knows
    else:
        assert drift > 1e-3  # g(q) of the payload moves the arm
        # ... downwards: the first motion follows -M^-1 g_payload.
        runner = episode.ClosedLoopRunner(r)
        model = runner.model
        runner.randomizer.apply(model, episode.draw(r, runner.randomizer, 0).params)
        runner.flange.apply(model, 1.0, np.zeros(3))  # the simulated robot: armature 0.1, the payload on
        comp = realistic.Compensation(r.arm, r.substeps, r.dt)
        bare = comp(q[0])
        comp.configure(1.0, np.zeros(3))
        g_payload = comp(q[0]) - bare
        data = mujoco.MjData(model)
        data.qpos[:] = q[0]
        mujoco.mj_forward(model, data)
        acc = np.zeros((1, 7))
        mujoco.mj_solveM(model, data, acc, -g_payload[None])
        acc = acc[0]
        step = q[1] - q[0]
        assert np.dot(step, acc) > 0.95 * np.linalg.norm(step) * np.linalg.norm(acc)


def test_widened_draws_leave_the_box_and_keep_its_middle():
    cfg = RandomizationConfig()
    wide = cfg.widened(2.0)
    assert wide.mass_pct == 20.0 and wide.damping == (2.5, 12.5) and wide.init_spread == cfg.init_spread
    r = recipe(realism={"widen": 2.0})
    model = episode.build_model(r)
    rand = episode.make_randomizer(model, r)
    box = Randomizer(model, r.randomization)
    np.testing.assert_array_equal(rand.catalogue(np.zeros(7)), box.catalogue(np.zeros(7)))
    damping = np.stack([rand.split(episode.draw(r, rand, i).params)["damping"] for i in range(20)])
    assert damping.min() < 5.0 or damping.max() > 10.0
    assert damping.min() >= 2.5 and damping.max() <= 12.5
    with pytest.raises(ConfigError, match="realism.widen"):
        recipe(realism={"widen": 0.5})


def test_feedback_tracks_the_reference_and_logs_what_it_applied():
    r = recipe(steps=120, task="multisine", gravity_compensation="true_model",
               realism={"feedback": {"enabled": True, "amplitude": [0.2, 0.2]}})
    runner = episode.ClosedLoopRunner(r)
    d = episode.draw(r, runner.randomizer, 0)
    runner.randomizer.apply(runner.model, d.params)
    res = realistic.simulate(r, runner.model, runner.data, d, d.real, None)
    lay, h = r.arm.layout, r.dt / r.substeps
    q_ref, _ = realism.reference(d.real, d.qpos0, np.arange(len(res.sens)) * h, 1.0)
    q = res.sens[:, lay.qpos]
    motion = np.abs(q_ref - d.qpos0).max()
    assert motion > 0.02
    assert np.sqrt(np.mean((q - q_ref) ** 2)) < 0.2 * motion
    # No latency, no compensation added: what the PD sent is what the motors applied.
    np.testing.assert_allclose(res.command, res.sens[:, lay.cmd], atol=1e-9)
    names = realism.names(7)
    kp = runner(0).realism[[names.index(f"feedback_kp_q{j}") for j in range(7)]]
    assert np.all(kp > 0) and kp[0] <= 600 and kp[6] <= 50


def test_a_realistic_attempt_is_deterministic_and_attempts_differ():
    r = load_recipe("realistic", {"steps": 40})
    a, b = episode.ClosedLoopRunner(r), episode.ClosedLoopRunner(r)
    x, y = a(5), b(5)
    assert x.reason is None
    np.testing.assert_array_equal(x.realism, y.realism)
    np.testing.assert_array_equal(x.u, y.u)
    np.testing.assert_array_equal(x.y, y.y)
    np.testing.assert_array_equal(x.u_cmd, y.u_cmd)
    assert not np.array_equal(a(6).realism, x.realism)


@pytest.mark.parametrize("over, message", [
    ({"encoder": {"noise": [1e-4, 1e-5]}}, "realism.encoder.noise"),
    ({"torque": {"offset": 2.0}}, "realism.torque.offset"),
    ({"timing": {"latency": [0.5, 2]}}, "realism.timing.latency"),
    ({"payload": {"configured": 1.5}}, "realism.payload"),
    ({"friction": {"stribeck_ratio": [0.5, 1.0]}}, "realism.friction.stribeck_ratio"),
    ({"feedback": {"kp": [1.0, 2.0]}}, "realism.feedback.kp"),
    ({"timing": {"log_physics_rate": True}, "encoder": {"pose_from_joints": False}}, "pose_from_joints"),
])
def test_bad_realism_names_the_field(over, message):
    with pytest.raises(ConfigError, match=message):
        recipe(realism=over)
