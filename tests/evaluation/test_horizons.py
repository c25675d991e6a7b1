import math

import numpy as np
import pytest

from robomorph.evaluation.horizons import (
    HorizonError,
    below,
    coverage,
    error_curve,
    groups_for,
    horizon_markdown,
    horizon_report,
    parse_horizons,
    quaternion_angle,
    spread_skill,
)

PANDA = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]


def _rot_z(theta):
    """Quaternion (x, y, z, w) of a rotation by ``theta`` about z."""
    return np.array([0.0, 0.0, math.sin(theta / 2), math.cos(theta / 2)])


def _rot_x(theta):
    return np.array([math.sin(theta / 2), 0.0, 0.0, math.cos(theta / 2)])


@pytest.mark.parametrize("a, b", [(0.2, 0.5), (0.0, 1e-5), (-1.0, 2.0), (0.0, 3.1)])
def test_quaternion_angle_is_the_rotation_between_them_with_either_sign(a, b):
    want = abs(b - a)
    qa, qb = _rot_z(a), _rot_z(b)
    assert quaternion_angle(qa, qb) == pytest.approx(want, rel=1e-9, abs=1e-12)
    assert quaternion_angle(qa, -qb) == pytest.approx(want, rel=1e-9, abs=1e-12)
    assert quaternion_angle(-qa, qb) == pytest.approx(want, rel=1e-9, abs=1e-12)
    # A prediction need not have unit norm: it is normalized first.
    assert quaternion_angle(qa, 3.0 * qb) == pytest.approx(want, rel=1e-9, abs=1e-12)


def test_quaternion_angle_across_axes_by_hand():
    # Rotations of 90 degrees about x and about z differ by 120 degrees (a well known case:
    # the product is a rotation of 2 acos(cos^2 45) = 2 acos(1/2) = 120 degrees).
    assert quaternion_angle(_rot_x(math.pi / 2), _rot_z(math.pi / 2)) == pytest.approx(2 * math.pi / 3)
    # Past 180 degrees the shorter way round is reported.
    assert quaternion_angle(_rot_z(0.0), _rot_z(2 * math.pi - 0.1)) == pytest.approx(0.1)


def test_groups_of_the_panda_layout_and_of_any_other_store():
    g = {x.name: x for x in groups_for(PANDA)}
    assert list(g) == ["joints", "ee_pos", "ee_rot"]
    assert g["joints"].channels == tuple(range(7, 14)) and g["joints"].unit == "mrad"
    assert g["ee_pos"].channels == (0, 1, 2) and g["ee_pos"].unit == "mm" and g["ee_pos"].kind == "distance"
    assert g["ee_rot"].channels == (3, 4, 5, 6) and g["ee_rot"].kind == "rotation"
    other = groups_for(["temp", "flow"], ["K", "l/s"])
    assert [(x.name, x.unit, x.channels, x.scale) for x in other] == [("temp", "K", (0,), 1.0), ("flow", "l/s", (1,), 1.0)]
    assert [x.unit for x in groups_for(["a"])] == [""]


def test_error_curves_equal_a_hand_computation():
    n, h = 2, 3
    y = np.zeros((n, h, len(PANDA)))
    y[..., 6] = 1.0  # identity orientation (w = 1)
    yhat = y.copy()
    # joints: trajectory 0 off by 0.002 rad on q0 at every step, trajectory 1 by 0.001 on q1 and q2.
    yhat[0, :, 7] = 0.002
    yhat[1, :, 8:10] = 0.001
    # position: trajectory 0 off by (3, 4, 0) mm at step 2 only (5 mm away).
    yhat[0, 1, 0:2] = [0.003, 0.004]
    # orientation: trajectory 1 turned by 0.01 rad about z at step 3, with the sign flipped.
    yhat[1, 2, 3:7] = -_rot_z(0.01)
    g = {x.name: x for x in groups_for(PANDA)}
    joints_ms = (0.002**2 / 7 + 2 * 0.001**2 / 7) / 2  # mean over joints, then over trajectories
    assert error_curve(y, yhat, g["joints"]) == pytest.approx([math.sqrt(joints_ms) * 1e3] * 3)
    assert error_curve(y, yhat, g["ee_pos"]) == pytest.approx([0.0, math.sqrt(25 / 2), 0.0])
    assert error_curve(y, yhat, g["ee_rot"]) == pytest.approx([0.0, 0.0, math.sqrt(10.0**2 / 2)])


def test_parse_horizons_in_steps_seconds_and_end():
    dt = 1 / 60
    assert parse_horizons(None, 800, dt) == [1, 15, 60, 300, 800]
    # Default items beyond a short horizon are dropped, not errors.
    assert parse_horizons("", 60, dt) == [1, 15, 60]
    assert parse_horizons("end, 0.5s, 2, 2", 100, dt) == [2, 30, 100]
    assert parse_horizons("0.001s", 100, dt) == [1]
    with pytest.raises(HorizonError, match="outside the evaluated horizon of 100 steps"):
        parse_horizons("1,2s", 100, dt)
    with pytest.raises(HorizonError, match="steps .* seconds .* or 'end'"):
        parse_horizons("soon", 100, dt)
    with pytest.raises(HorizonError, match="outside"):
        parse_horizons("0", 100, dt)


def test_coverage_equals_a_direct_count():
    rng = np.random.default_rng(0)
    y, mean = rng.normal(size=(5, 8, 3)), rng.normal(size=(5, 8, 3))
    std = rng.uniform(0.2, 2.0, size=(5, 8, 3))
    steps = [1, 4, 8]
    cov = coverage(y, mean, std, steps)
    for s in (1, 2):
        for j, k in enumerate(steps):
            inside = sum(abs(y[i, k - 1, c] - mean[i, k - 1, c]) <= s * std[i, k - 1, c]
                         for i in range(5) for c in range(3))
            assert cov[f"{s}sigma"][j] == inside / 15
    only = coverage(y, mean, std, [2], channels=(1,))
    assert only["1sigma"] == [np.mean(np.abs(y[:, 1, 1] - mean[:, 1, 1]) <= std[:, 1, 1])]


def test_horizon_report_and_table():
    rng = np.random.default_rng(1)
    y = rng.normal(size=(4, 10, len(PANDA)))
    preds = {"model": y + 0.001, "hold": np.repeat(y[:, :1], 10, axis=1)}
    std = np.full_like(y, 0.002)
    rep = horizon_report(y, preds, PANDA, 0.1, [1, 5, 10], std)
    assert rep["steps"] == [1, 5, 10] and rep["seconds"] == pytest.approx([0.1, 0.5, 1.0])
    assert set(rep["rms"]) == {"model", "hold"} and set(rep["rms"]["model"]) == {"joints", "ee_pos", "ee_rot"}
    assert rep["rms"]["model"]["joints"] == pytest.approx([1.0] * 3)  # 1 mrad on every joint
    assert rep["rms"]["model"]["ee_pos"] == pytest.approx([math.sqrt(3)] * 3)  # (1, 1, 1) mm away
    assert rep["rms"]["hold"]["joints"][0] == 0.0  # hold repeats the first query value here
    assert rep["calibration"]["all"]["1sigma"] == [1.0] * 3
    assert rep["quantities"]["ee_pos"] == {"unit": "mm", "channels": ["ee_x", "ee_y", "ee_z"], "kind": "distance"}
    table = horizon_markdown(rep, ("model", "hold", "nominal_physics"))
    rows = markdown_rows(table)
    assert ["joints [mrad]", "model", "1", "1", "1"] in rows and "step 5 (0.5 s)" in rows[0]
    assert ["inside ±2σ [%]", "model", "100.0", "100.0", "100.0"] in rows and "nominal_physics" not in table
    assert "calibration" not in horizon_report(y, preds, PANDA, 0.1, [1])


def markdown_rows(table: str) -> list[list[str]]:
    """The cells of a pipe table's lines (header, separator and rows), stripped."""
    return [[c.strip() for c in line.strip().strip("|").split("|")] for line in table.splitlines() if line.startswith("|")]


def test_below_hold_counts_the_steps_where_the_model_beats_hold():
    y = np.zeros((2, 5, len(PANDA)))
    y[..., 6] = 1.0
    model, hold = y.copy(), y.copy()
    model[..., 7:] = 0.01
    hold[..., 7:] = np.array([0.0, 0.02, 0.02, 0.005, 0.02])[None, :, None]
    g = {x.name: x for x in groups_for(PANDA)}
    assert below(y, model, hold, g["joints"]) == {"fraction": 0.6, "first_not_below": 1}
    assert below(y, model, model + 1.0, g["joints"]) == {"fraction": 1.0, "first_not_below": None}
    rep = horizon_report(y, {"model": model, "hold": hold}, PANDA, 0.1, [1])
    assert rep["below"]["hold"]["joints"]["fraction"] == 0.6


def test_shares_read_100_percent_only_when_every_step_is_below():
    from robomorph.evaluation.horizons import _percent

    assert _percent(1.0) == "100" and _percent(0.0) == "0"
    assert _percent(799 / 800) == "99.9"  # one step above hold is not "100 %"
    assert _percent(1 / 800) == "0.1"
    assert _percent(0.94) == "94"


def test_the_report_ranks_the_std_per_quantity_and_the_table_shows_it():
    rng = np.random.default_rng(1)
    n, h = 64, 4
    names = [f"q{i}" for i in range(7)]
    y = np.zeros((n, h, 7))
    std = rng.uniform(0.01, 1.0, size=(n, h, 7))
    mean = std * rng.choice([-1.0, 1.0], size=std.shape)  # each error exactly its std: a perfect ranking
    rep = horizon_report(y, {"model": mean}, names, 1 / 60, [1, h], std)
    assert rep["skill"]["all"] == pytest.approx([1.0, 1.0]) and rep["skill"]["joints"] == pytest.approx([1.0, 1.0])
    assert "std-error rank corr." in horizon_markdown(rep)
    assert "skill" not in horizon_report(y, {"model": mean}, names, 1 / 60, [1, h])  # no std, no skill



def test_the_table_gives_the_joints_coverage_beside_all_outputs_where_there_are_others():
    rng = np.random.default_rng(2)
    names = PANDA
    y = rng.normal(size=(16, 5, len(names)))
    std = np.ones_like(y)
    mean = y.copy()
    mean[..., 7:] += 3.0  # the joints miss by three stds, the end effector not at all
    table = horizon_markdown(horizon_report(y, {"model": mean}, names, 1 / 60, [1, 5], std))
    rows = [[c.strip() for c in line.strip("|").split("|")] for line in table.splitlines() if line.startswith("| inside")]
    assert ["inside ±2σ [%], joints", "model", "0.0", "0.0"] in rows
    assert any(r[0] == "inside ±2σ [%]" and r[2] != "0.0" for r in rows)
    joints_only = horizon_markdown(horizon_report(y[..., 7:], {"model": mean[..., 7:]}, names[7:], 1 / 60, [1], std[..., 7:]))
    assert ", joints" not in joints_only


def test_spread_skill_is_one_for_a_spread_that_orders_the_errors_and_near_zero_for_one_that_does_not():
    rng = np.random.default_rng(0)
    n, h = 400, 5
    scale = rng.uniform(0.1, 10.0, size=(n, 1, 2)) * np.ones((1, h, 2))
    y = np.zeros((n, h, 2))
    mean = scale * 0.7  # the error grows with the spread, window by window
    assert spread_skill(y, mean, scale, [1, h]) == pytest.approx([1.0, 1.0])
    shuffled = scale[rng.permutation(n)]
    assert np.all(np.abs(spread_skill(y, mean, shuffled, [1, 3, h])) < 0.15)
    # A spread that is the same in every window ranks nothing: no figure rather than a made-up one.
    assert spread_skill(y, mean, np.ones_like(scale), [1]) == [None]

