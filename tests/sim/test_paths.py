"""The OSC tasks' reference paths: start at rest, consistent derivatives, geometry, seeds."""

import numpy as np
import pytest

from robomorph.sim import paths

DT = 1 / 60


def _fit_circle(points):
    """Centre and radius of the circle through (N, 2) points (algebraic least squares)."""
    a = np.column_stack([2 * points, np.ones(len(points))])
    (cx, cy, c), *_ = np.linalg.lstsq(a, (points**2).sum(1), rcond=None)
    centre = np.array([cx, cy])
    return centre, np.sqrt(c + centre @ centre)


@pytest.mark.parametrize("task", paths.TASKS)
def test_paths_start_at_the_ee_at_rest_with_consistent_derivatives(task):
    start = np.array([0.3, -0.1, 0.5])
    pos, vel, acc = paths.PATHS[task](np.random.default_rng(0), start, 600, DT,
                                    paths.CircleConfig() if task == "circle" else paths.SpiralConfig())
    assert pos.shape == vel.shape == acc.shape == (600, 3)
    np.testing.assert_array_equal(pos[0], start)
    np.testing.assert_allclose(vel[0], 0, atol=1e-12)
    np.testing.assert_allclose(acc[0], 0, atol=1e-12)
    # The analytic derivatives agree with finite differences of the sampled path.
    np.testing.assert_allclose(np.gradient(pos, DT, axis=0)[1:-1], vel[1:-1], atol=2e-3)
    np.testing.assert_allclose(np.gradient(vel, DT, axis=0)[1:-1], acc[1:-1], atol=2e-2)


def test_circle_lies_in_the_yz_plane_with_a_radius_in_range():
    cfg = paths.CircleConfig()
    for seed in range(5):
        pos, _, _ = paths.circle_path(np.random.default_rng(seed), np.zeros(3), 1000, DT, cfg)
        assert np.all(pos[:, 0] == 0)
        centre, radius = _fit_circle(pos[:, 1:])
        assert cfg.radius[0] <= radius <= cfg.radius[1]
        np.testing.assert_allclose(np.linalg.norm(pos[:, 1:] - centre, axis=1), radius, atol=1e-9)


def test_spiral_circles_in_xy_and_climbs_by_the_drawn_amount():
    cfg = paths.SpiralConfig()
    signs = set()
    for seed in range(8):
        pos, vel, _ = paths.spiral_path(np.random.default_rng(seed), np.zeros(3), 1000, DT, cfg)
        climb = pos[-1, 2] - pos[0, 2]
        assert cfg.climb[0] - 1e-12 <= abs(climb) <= cfg.climb[1] + 1e-12
        signs.add(np.sign(climb))
        assert np.all(np.diff(pos[:, 2]) * np.sign(climb) >= 0)  # monotonic
        # The XY part is a circle: constant distance to its centre, radius in range.
        centre, radius = _fit_circle(pos[:, :2])
        assert cfg.radius[0] <= radius <= cfg.radius[1]
        np.testing.assert_allclose(np.linalg.norm(pos[:, :2] - centre, axis=1), radius, atol=1e-9)
        assert np.allclose(vel[200:, 2], vel[-1, 2])  # steady climb after the ramp
    assert signs == {-1.0, 1.0}


@pytest.mark.parametrize("task", paths.TASKS)
def test_same_seed_same_path_other_seed_other_path(task):
    draw = paths.PATHS[task]
    cfg = paths.CircleConfig() if task == "circle" else paths.SpiralConfig()
    a = draw(np.random.default_rng(7), np.zeros(3), 300, DT, cfg)
    b = draw(np.random.default_rng(7), np.zeros(3), 300, DT, cfg)
    c = draw(np.random.default_rng(8), np.zeros(3), 300, DT, cfg)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert not np.allclose(a[0], c[0])
