"""The total-torque smoother: its frames re-enact the generator, its linear step is exact least
squares, and it follows a robot far past where any forward simulation leaves."""

import numpy as np
import pytest

CONTEXT, HORIZON = 100, 300


@pytest.fixture(scope="module")
def robot(simulated_store):
    """(backbone, recorded u, y, true params) of one robot of a 400-step multi-sine store."""
    from robomorph.data.store import open_store
    from robomorph.identification.backbone import PhysicsBackbone, parameter_layout

    ds = open_store(simulated_store(robots=2, steps=CONTEXT + HORIZON, seed=5))
    bb = PhysicsBackbone(parameter_layout(dict(ds.attrs)), "total", nthread=1)
    yield bb, ds.read("u")[0].astype(np.float64), ds.read("y")[0].astype(np.float64), ds.read("params")[0]
    bb.close()


def _frames(bb, params):
    from robomorph.identification.smoother import FrameMap

    return FrameMap(bb.ident.model, lambda m: bb.ident.randomizer.apply(m, params), bb.substeps, True,
                    bb.ident.engine.rollout)


def _run(frames, q0, u, n):
    x = np.r_[q0, np.zeros_like(q0)][None]
    out = []
    for k in range(n):
        x = frames(x, u[k:k + 1])
        out.append(x[0, :7])
    return np.array(out)


def test_the_true_robots_frames_re_enact_the_recorded_trajectory_and_the_catalogues_do_not(robot):
    bb, u, y, params = robot
    q = y[:, 7:]
    true = _run(_frames(bb, params), q[0], u, 60)  # the generator starts at rest
    cat = _run(_frames(bb, bb.catalogue(q[0])), q[0], u, 60)
    err_true, err_cat = np.abs(true - q[1:61]).max(), np.abs(cat - q[1:61]).max()
    assert err_true < 2e-5  # float32 storage of u and y, grown over a second
    assert err_cat > 50 * err_true


def test_the_linear_smoother_is_the_least_squares_solution_and_its_covariance():
    from robomorph.identification.kalman import rts

    rng = np.random.default_rng(0)
    h, n = 6, 4
    jac = np.eye(n)[None] + 0.3 * rng.standard_normal((h, n, n))
    nominal, xbar = rng.standard_normal((h, n)), rng.standard_normal((h, n))
    x0, p0 = rng.standard_normal(n), np.diag(rng.uniform(0.1, 1, n))
    q = np.diag(rng.uniform(0.01, 0.1, n))
    meas = rng.standard_normal((h + 1, n))
    weight = rng.uniform(0, 3, (h + 1, n)) * (rng.uniform(size=(h + 1, n)) > 0.3)
    ms, ps = rts(x0, p0, nominal, jac, xbar, q, meas, weight)
    # The same problem as one dense least squares over all states.
    size = (h + 1) * n
    hess, grad = np.zeros((size, size)), np.zeros(size)

    def add(rows, target, w):  # w (||rows x - target||^2 weighted by matrix w)
        nonlocal hess, grad
        hess += rows.T @ w @ rows
        grad += rows.T @ w @ target

    sel = lambda k: np.eye(size)[k * n:(k + 1) * n]  # noqa: E731
    add(sel(0), x0, np.linalg.inv(p0))
    for k in range(h):
        add(sel(k + 1) - jac[k] @ sel(k), nominal[k] - jac[k] @ xbar[k], np.linalg.inv(q))
    for k in range(h + 1):
        add(sel(k), meas[k], np.diag(weight[k]))
    x = np.linalg.solve(hess, grad).reshape(h + 1, n)
    np.testing.assert_allclose(ms, x, atol=1e-9)
    cov = np.linalg.inv(hess)
    for k in range(h + 1):
        np.testing.assert_allclose(ps[k], cov[k * n:(k + 1) * n, k * n:(k + 1) * n], atol=1e-9)


def test_the_smoother_follows_the_robot_where_its_simulation_leaves_and_beats_the_decoder(robot):
    from robomorph.core.velocity import estimate_velocity
    from robomorph.identification.smoother import Smoother

    bb, u, y, params = robot
    q = y[:, 7:]
    truth = q[CONTEXT:]
    torque = u[CONTEXT - 1:-1]
    v_last = estimate_velocity(q[None, :CONTEXT], bb.dt)[0]
    # A decoder off by a slow drift that grows to 30 mrad, with that spread as its std.
    t = np.arange(1, HORIZON + 1)[:, None]
    size = 0.03 * np.minimum(1.0, t / 60)
    decoder = truth + size * np.sin(0.02 * t + np.arange(7))
    frames = _frames(bb, params)
    forward = [q[CONTEXT - 1]]
    x = np.r_[q[CONTEXT - 1], v_last][None]
    for k in range(HORIZON):
        x = frames(x, torque[k:k + 1])
        forward.append(x[0, :7])
    forward_err = np.abs(np.array(forward[1:]) - truth).max(axis=1)
    assert forward_err[-1] > 0.05  # the simulation forward has left the trajectory
    smoother = Smoother(frames)
    mean, cov = smoother(q[CONTEXT - 1], v_last, torque, decoder, np.broadcast_to(size, decoder.shape))
    err = np.abs(mean - truth).max(axis=1)
    dec = np.abs(decoder - truth).max(axis=1)
    assert mean.shape == truth.shape and cov.shape == (HORIZON, 7, 7)
    assert smoother.last_steps > 0 and np.isfinite(smoother.last_cost)
    middle = slice(60, HORIZON - 60)  # where the torques on both sides pin the robot
    assert err[middle].max() < 0.1 * dec[middle].min()
    assert err[:15].max() < 1e-3  # the context's end holds the first steps
    np.testing.assert_array_less(0.0, np.diagonal(cov, axis1=1, axis2=2))


def test_a_decoder_far_from_any_physical_path_is_smoothed_in_stages(robot):
    """Out of distribution (chirp torques) a confident decoder can be so far from every path the
    physics allows that Gauss-Newton started at it stalls; the horizon grown in stages from the
    context's end recovers the first second, and its cost is the lower."""
    import dataclasses

    from robomorph.core.velocity import estimate_velocity
    from robomorph.identification.smoother import Smoother, SmootherConfig

    bb, u, y, params = robot
    q = y[:, 7:]
    truth, torque = q[CONTEXT:], u[CONTEXT - 1:-1]
    v_last = estimate_velocity(q[None, :CONTEXT], bb.dt)[0]
    t = np.arange(1, HORIZON + 1)[:, None]
    decoder = truth + 1.0 * np.minimum(1.0, t / 10) * np.sin(0.3 * t + np.arange(7))  # a radian off, sure of it
    std = np.full(decoder.shape, 2e-3)
    frames = _frames(bb, params)
    direct = Smoother(frames, dataclasses.replace(SmootherConfig(), grow=0))
    mean_direct, _ = direct(q[CONTEXT - 1], v_last, torque, decoder, std)
    staged = Smoother(frames)
    mean, cov = staged(q[CONTEXT - 1], v_last, torque, decoder, std)
    assert direct.last_cost > SmootherConfig().fail_cost * decoder.size  # the direct solve stalled
    assert staged.grown and staged.last_cost < direct.last_cost
    first = slice(0, 60)
    assert np.abs(mean[first] - truth[first]).max() < 0.2 * np.abs(mean_direct[first] - truth[first]).max()
    assert np.isfinite(cov).all()


def test_a_path_that_leaves_the_joint_range_is_handed_to_the_decoder_from_where_they_parted():
    from robomorph.identification.smoother import handover_steps

    h, nj = 50, 2
    box = (np.full(nj, -1.0), np.full(nj, 1.0))
    decoder, std = np.zeros((3, h, nj)), np.full((3, h, nj), 0.01)
    q = np.zeros((3, h, nj))
    q[0, 20:, 1] = np.linspace(0.0, 2.0, h - 20)  # parts from the decoder at step 21, leaves at 35
    q[1, :, 0] = 0.5  # apart from the decoder throughout, but inside the range: kept
    q[2, :, 0] = 1.5  # outside from the start
    parted = 20 + int(np.argmax(np.abs(q[0, 20:, 1]) > 0.05))
    start = handover_steps(q, decoder, std, box, 5.0)
    assert start.tolist() == [parted, h, 0]
    assert handover_steps(q, decoder, std, None, 5.0).tolist() == [h, h, h]


def test_centres_of_mass_fitted_for_total_torques_put_gravity_where_the_robot_has_it(robot):
    from robomorph.identification.identify import GRAVITY_KINDS, KINDS, ParameterSpace
    from robomorph.identification.regressor import RegressorIdentifier

    bb, u, y, params = robot
    q = y[:CONTEXT, 7:]
    true_g = _frames(bb, params).gravity(q)
    errors = {}
    for kinds in (KINDS, GRAVITY_KINDS):
        space = ParameterSpace.of(bb.ident.randomizer, bb.recipe.randomization, kinds)
        fit = RegressorIdentifier(bb.recipe, space, bb.ident.randomizer, "total").fit(bb.catalogue(q[0]), q,
                                                                                       u[:CONTEXT])
        errors[len(kinds)] = np.sqrt(np.mean((_frames(bb, fit).gravity(q) - true_g) ** 2))
    assert errors[len(GRAVITY_KINDS)] < 0.5 * errors[len(KINDS)]


def test_bad_settings_and_shapes_are_refused_in_one_line(robot):
    from robomorph.identification.smoother import Smoother, SmootherConfig, SmootherError

    for bad in ({"q_std": 0.0}, {"alphas": ()}, {"alphas": (1.0, -2.0)}, {"iterations": 0}, {"tol": 1.0},
                {"jacobian_substeps": 0}, {"grow": -1}, {"fail_cost": 0.0}, {"handover": 0.0}):
        with pytest.raises(SmootherError):
            SmootherConfig(**bad)
    bb, u, y, params = robot
    with pytest.raises(SmootherError, match="shaped as the decoder"):
        Smoother(_frames(bb, params))(y[0, 7:], np.zeros(7), u[:5], y[1:6, 7:], np.ones((4, 7)))
