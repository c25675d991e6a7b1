import numpy as np
import pytest

from robomorph.core.velocity import estimate_velocity
from robomorph.evaluation.baselines import ARX, TrainedARX, hold


def test_hold_is_exact_on_a_constant_trajectory():
    y = np.full((3, 50, 4), 2.5)
    u = np.random.default_rng(0).normal(size=(3, 50, 2))
    pred = hold(u[:, :20], y[:, :20], u[:, 20:])
    assert pred.shape == (3, 30, 4)
    np.testing.assert_array_equal(pred, y[:, 20:])


def _linear_system(rng, n_traj=3, steps=400, n_u=2, n_y=3, u_rng=None):
    """y[t] = A1 y[t-1] + A2 y[t-2] + B1 u[t-1] + B2 u[t-2] + c, stable (``u_rng``: inputs
    drawn from another stream, the system staying the one ``rng`` draws)."""
    a1 = 0.5 * np.eye(n_y) + 0.05 * rng.normal(size=(n_y, n_y))
    a2 = -0.2 * np.eye(n_y)
    b1, b2 = rng.normal(size=(n_y, n_u)), 0.3 * rng.normal(size=(n_y, n_u))
    c = rng.normal(size=n_y)
    u = (u_rng or rng).normal(size=(n_traj, steps, n_u))
    y = np.zeros((n_traj, steps, n_y))
    for t in range(2, steps):
        y[:, t] = y[:, t - 1] @ a1.T + y[:, t - 2] @ a2.T + u[:, t - 1] @ b1.T + u[:, t - 2] @ b2.T + c
    return u, y


def test_arx_is_exact_on_a_linear_system():
    u, y = _linear_system(np.random.default_rng(0))
    arx = ARX(na=2, nb=2)
    pred = arx(u[:, :150], y[:, :150], u[:, 150:])
    assert pred.shape == y[:, 150:].shape and arx.diverged == 0
    np.testing.assert_allclose(pred, y[:, 150:], atol=1e-5 * np.abs(y).max())


def test_arx_too_low_an_order_is_not_exact():
    u, y = _linear_system(np.random.default_rng(0))
    pred = ARX(na=1, nb=1)(u[:, :150], y[:, :150], u[:, 150:])
    assert np.abs(pred - y[:, 150:]).max() > 1e-2


def test_arx_never_sees_the_query_outputs():
    u, y = _linear_system(np.random.default_rng(1))
    a = ARX()(u[:, :150], y[:, :150], u[:, 150:])
    y2 = y.copy()
    y2[:, 150:] = 1e6
    np.testing.assert_array_equal(a, ARX()(u[:, :150], y2[:, :150], u[:, 150:]))


def test_arx_divergence_falls_back_to_hold_and_is_counted():
    t = np.arange(400)
    y = (1.05 ** t)[None, :, None] * np.ones((2, 1, 1))
    u = np.random.default_rng(0).normal(size=(2, 400, 1)) * 1e-6
    arx = ARX(na=1, nb=1)
    pred = arx(u[:, :100], y[:, :100], u[:, 100:])
    assert arx.diverged == 2
    np.testing.assert_array_equal(pred, np.repeat(y[:, 99:100], 300, axis=1))


def test_arx_needs_enough_context():
    u, y = _linear_system(np.random.default_rng(0))
    with pytest.raises(ValueError, match="longer context"):
        ARX(na=4, nb=4)(u[:, :20], y[:, :20], u[:, 20:40])
    with pytest.raises(ValueError, match="orders"):
        ARX(na=0)


def test_velocity_estimate_is_exact_on_a_cubic():
    dt = 0.01
    t = np.arange(30) * dt
    q = np.stack([1 + 2 * t - 3 * t**2 + 0.5 * t**3, np.sin(0 * t)], axis=-1)[None]
    v = estimate_velocity(q, dt)
    t_end = t[-1]
    assert v.shape == (1, 2)
    assert v[0, 0] == pytest.approx(2 - 6 * t_end + 1.5 * t_end**2, rel=1e-9)
    assert v[0, 1] == pytest.approx(0.0, abs=1e-12)


def _blocks(u, y, size=2):
    return [(u[i:i + size], y[i:i + size]) for i in range(0, len(u), size)]


def test_arx_fitted_on_training_data_is_exact_on_new_trajectories_of_the_same_system():
    u, y = _linear_system(np.random.default_rng(0), n_traj=5, steps=200)
    arx = TrainedARX(na=2, nb=2).fit(_blocks(u, y))
    assert arx.trajectories == 5
    # other inputs, same system: a context of only 3 steps suffices (no per-context fit)
    u2, y2 = _linear_system(np.random.default_rng(0), n_traj=4, steps=120, u_rng=np.random.default_rng(9))
    pred = arx(u2[:, :3], y2[:, :3], u2[:, 3:])
    assert pred.shape == y2[:, 3:].shape and arx.diverged == 0
    np.testing.assert_allclose(pred, y2[:, 3:], atol=1e-5 * np.abs(y2).max())
    poisoned = y2.copy()
    poisoned[:, 3:] = 1e6  # the query outputs are never read
    np.testing.assert_array_equal(pred, arx(u2[:, :3], poisoned[:, :3], u2[:, 3:]))
    with pytest.raises(ValueError, match="context of at least 2"):
        arx(u2[:, :1], y2[:, :1], u2[:, 1:])


def test_arx_fitted_on_training_data_holds_what_diverges_and_counts_it():
    t = np.arange(200)
    y = (1.05 ** t)[None, :, None] * np.ones((3, 1, 1))
    u = np.random.default_rng(0).normal(size=(3, 200, 1)) * 1e-6
    arx = TrainedARX(na=1, nb=1).fit([(u, y)])
    pred = arx(u[:, :20], y[:, :20], u[:, 20:])
    assert arx.diverged == 3
    np.testing.assert_array_equal(pred, np.repeat(y[:, 19:20], 180, axis=1))
    with pytest.raises(ValueError, match="at least one training trajectory"):
        TrainedARX().fit([])


def test_constant_velocity_and_acceleration_are_exact_on_their_own_motions():
    """A line is continued exactly by constant_velocity, a parabola by constant_acceleration;
    neither is exact on the other's motion, and neither reads the query outputs."""
    from robomorph.evaluation.baselines import constant_acceleration, constant_velocity

    t = np.arange(30, dtype=np.float64)[None, :, None]  # (1, 30, 1)
    line = 0.3 + 0.02 * t
    parab = 0.1 - 0.01 * t + 0.003 * t**2
    y = np.concatenate([line, parab], axis=-1)  # (1, 30, 2)
    c = 20
    u = np.random.default_rng(0).normal(size=(1, 30, 3))
    cv = constant_velocity(u[:, :c], y[:, :c], u[:, c:])
    ca = constant_acceleration(u[:, :c], y[:, :c], u[:, c:])
    assert cv.shape == ca.shape == (1, 10, 2)
    np.testing.assert_allclose(cv[..., 0], y[:, c:, 0], atol=1e-12)
    np.testing.assert_allclose(ca[..., 1], y[:, c:, 1], atol=1e-12)
    np.testing.assert_allclose(ca[..., 0], y[:, c:, 0], atol=1e-12)  # a line has zero acceleration
    assert np.abs(cv[..., 1] - y[:, c:, 1]).max() > 0.01
    # Causal: changing what follows the context changes nothing.
    y2 = y.copy()
    y2[:, c:] += 5.0
    np.testing.assert_array_equal(constant_acceleration(u[:, :c], y2[:, :c], u[:, c:]), ca)


def test_kinematic_baselines_refuse_too_short_a_context():
    from robomorph.evaluation.baselines import constant_acceleration, constant_velocity

    y = np.zeros((2, 2, 3))
    u = np.zeros((2, 5, 1))
    assert constant_velocity(u[:, :2], y, u[:, 2:]).shape == (2, 3, 3)
    with pytest.raises(ValueError, match="at least 3 steps"):
        constant_acceleration(u[:, :2], y, u[:, 2:])
    with pytest.raises(ValueError, match="at least 2 steps"):
        constant_velocity(u[:, :1], y[:, :1], u[:, 1:])


def _double_integrator(rng, n_traj=4, steps=260, n=2, offset=0.3):
    """Joints driven as double integrators through an input matrix, with a constant torque offset."""
    gain = np.array([[0.004, 0.001], [-0.002, 0.006]])[:n, :n]
    u = rng.normal(size=(n_traj, steps, n)).cumsum(1) * 0.1
    y = np.zeros((n_traj, steps, n))
    for t in range(1, steps - 1):
        y[:, t + 1] = 2 * y[:, t] - y[:, t - 1] + (u[:, t] + offset) @ gain.T
    return u, y


def test_accel_arx_recovers_a_double_integrator_and_the_trained_one_reads_the_offset_from_the_context():
    from robomorph.evaluation.baselines import AccelARX, TrainedAccelARX, constant_velocity

    rng = np.random.default_rng(1)
    u, y = _double_integrator(rng)
    c = 200
    truth = y[:, c:]
    cv_err = np.abs(constant_velocity(u[:, :c], y[:, :c], u[:, c:]) - truth).max()
    own = AccelARX()
    pred = own(u[:, :c], y[:, :c], u[:, c:])
    assert pred.shape == truth.shape and own.diverged == 0
    assert np.abs(pred - truth).max() < 1e-2 * cv_err
    # Trained without the offset, the constant re-estimated on each context recovers it.
    u_train, y_train = _double_integrator(np.random.default_rng(2), offset=0.0)
    trained = TrainedAccelARX().fit([(u_train, y_train)])
    assert trained.trajectories == 4
    pred = trained(u[:, :c], y[:, :c], u[:, c:])
    assert np.abs(pred - truth).max() < 1e-2 * cv_err
    # Causal: what follows the context does not change the prediction.
    y2 = y.copy()
    y2[:, c:] += 1.0
    np.testing.assert_array_equal(trained(u[:, :c], y2[:, :c], u[:, c:]), pred)


def test_accel_arx_refuses_too_short_a_context_and_an_unfitted_model():
    from robomorph.evaluation.baselines import AccelARX, TrainedAccelARX

    u, y = _double_integrator(np.random.default_rng(0), steps=30)
    with pytest.raises(ValueError, match="accel_arx needs a context of at least"):
        AccelARX()(u[:, :10], y[:, :10], u[:, 10:])
    with pytest.raises(ValueError, match="fit accel_arx_train"):
        TrainedAccelARX()(u[:, :10], y[:, :10], u[:, 10:])


def test_a_trained_free_run_from_a_few_samples_is_judged_against_the_training_band():
    """From a context of a few samples (a benchmark's free run) the context's own band says
    nothing: with ``band="training"`` an exact model's run is kept, not held."""
    rng = np.random.default_rng(3)
    u, y = _linear_system(rng, n_traj=2, steps=300)
    lag = 2
    by_context = TrainedARX(2, 2).fit([(u, y)])
    by_training = TrainedARX(2, 2, band="training").fit([(u, y)])
    held = by_context(u[:, :lag], y[:, :lag], u[:, lag:])
    kept = by_training(u[:, :lag], y[:, :lag], u[:, lag:])
    assert by_context.diverged == 2 and by_training.diverged == 0
    np.testing.assert_allclose(kept, y[:, lag:], rtol=1e-5, atol=1e-4 * np.abs(y).max())
    np.testing.assert_array_equal(held, np.repeat(y[:, lag - 1:lag], 298, axis=1))
