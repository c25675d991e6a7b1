"""Joints that held still in the context: their friction loss as a mixture (robomorph.identification.stiction)."""

import numpy as np
import pytest

from robomorph.data.store import open_store
from robomorph.identification.backbone import PhysicsBackbone, parameter_layout
from robomorph.identification.identify import ContextProblem
from robomorph.identification.regressor import RegressorIdentifier
from robomorph.identification.stiction import FrictionMixture
from tests.identification.test_regressor import CONTEXT


@pytest.fixture(scope="module")
def fitted(simulated_store):
    """Six fully randomized robots from rest, each fitted by the regression: (store arrays,
    backbone, estimates, held joints)."""
    ds = open_store(simulated_store(robots=6, steps=CONTEXT, seed=4))
    y, u, params = ds.read("y").astype(np.float64), ds.read("u_cmd").astype(np.float64), ds.read("params")
    bb = PhysicsBackbone(parameter_layout(ds.attrs), "command", nthread=1)
    reg = RegressorIdentifier(bb.recipe, bb.ident.space, bb.ident.randomizer, "command")
    est, held = [], []
    for b in range(len(y)):
        est.append(reg.fit(bb.catalogue(y[b, 0, 7:]), y[b, :, 7:], u[b]))
        held.append(reg.last_held.copy())
    yield y, u, params, bb, np.stack(est), np.stack(held)
    bb.close()


def _context_rms(bb, params, y, u) -> float:
    problem = ContextProblem(bb.ident, params, y[:, 7:], u, np.zeros(7))
    return float(np.sqrt(np.mean(problem.joint_error(bb.ident.space.to_unit(params[bb.ident.space.index])[None]) ** 2)))


def test_held_joints_are_those_whose_friction_the_context_cannot_see(fitted):
    """Raising a held joint's friction loss to the top of its range leaves the re-enacted
    context as it was (the joint held anyway); raising a slipping joint's changes it many times over."""
    y, u, _, bb, est, held = fitted
    assert held.any() and (~held).any()  # both kinds occur, so both assertions below are exercised
    mix = FrictionMixture(bb.ident, 3)
    checked = {True: 0, False: 0}
    for b in range(len(y)):
        base = _context_rms(bb, est[b], y[b], u[b])
        for j, (k, _, hi) in mix.friction.items():
            if est[b, k] > 0.9 * hi:
                continue  # already near the top: raising it changes little either way
            raised = est[b].copy()
            raised[k] = hi
            rms = _context_rms(bb, raised, y[b], u[b])
            # Held: unchanged (up to where the re-enacted motion strays from the recorded states the
            # regression read; 4 % at most here). Slipping: the error grows by 2 to 70 times.
            change = abs(rms - base) / base
            assert change < 0.1 if held[b, j] else change > 0.5
            checked[bool(held[b, j])] += 1
    assert checked[True] and checked[False]


def test_members_span_the_held_joints_range_and_keep_the_rest():
    class Ident:  # only what FrictionMixture reads: the space and the number of models
        from robomorph.identification.identify import ParameterSpace

        space = ParameterSpace(("damping_q0", "frictionloss_q0", "frictionloss_q1"), np.array([2, 5, 6]),
                               np.array([1.0, 0.2, 0.4]), np.array([3.0, 1.2, 2.4]))
        engine = type("Engine", (), {"models": [None] * 9})()

    mix = FrictionMixture(Ident(), 4)
    params = np.arange(8, dtype=np.float64)
    np.testing.assert_array_equal(mix.candidates(params, np.zeros(7, bool)), params[None])
    held = np.zeros(7, bool)
    held[1] = True
    members = mix.candidates(params, held)
    assert members.shape == (4, 8)
    np.testing.assert_allclose(members[:, 6], 0.4 + np.array([0.125, 0.375, 0.625, 0.875]) * 2.0)
    np.testing.assert_array_equal(np.delete(members, 6, axis=1), np.repeat(np.delete(params, 6)[None], 4, 0))
    with pytest.raises(ValueError, match="at least 2"):
        FrictionMixture(Ident(), 1)
    with pytest.raises(ValueError, match="needs as many models"):
        FrictionMixture(Ident(), 10)


def test_weights_share_alike_members_and_never_rule_out_the_truth(fitted):
    """On the recorded robot itself (its stored parameters: the context is re-enacted to float32
    storage), the members that hold the joint as it held re-enact the context alike and share
    the weight equally, those that slip get none, and the true friction loss lies within one
    member spacing of the members with weight."""
    y, u, params, bb, _, held = fitted
    mix = FrictionMixture(bb.ident, 9)
    windows = [b for b in range(len(y)) if held[b].any()]
    assert windows
    slipped = 0
    for b in windows:
        truth = params[b].astype(np.float64)
        members, w, qvel_end = mix.weigh(truth, held[b], y[b, :, 7:], u[b], np.zeros(7))
        assert members.shape == (9, len(truth)) and w.shape == (9,) and qvel_end.shape == (9, 7)
        assert np.all(w >= 0) and w.sum() == pytest.approx(1.0)
        err = np.array([_context_rms(bb, m, y[b], u[b]) for m in members])
        same = np.isclose(err[:, None], err[None, :], rtol=1e-9, atol=0)
        for i in range(9):
            np.testing.assert_allclose(w[same[i]], w[i], rtol=1e-6)
        assert np.all(w[err > 10 * err.min()] < 1e-6)
        slipped += int(np.sum(err > 10 * err.min()))
        for j in np.flatnonzero(held[b]):
            k, lo, hi = mix.friction[j]
            kept = members[w > 1e-3, k]
            step = (hi - lo) / 9
            assert kept.min() - step <= truth[k] <= kept.max() + step
        # Deterministic: the same context gives the same members and weights.
        again = mix.weigh(truth, held[b], y[b, :, 7:], u[b], np.zeros(7))
        np.testing.assert_array_equal(again[1], w)
    assert slipped  # some members slipped where the robot held: the weights had something to rule out


def test_members_between_alike_extremes_are_not_simulated_and_change_nothing(fitted):
    """Where the lowest and the highest friction losses re-enact a context (or a horizon) to the bit, every member
    between does: the shortcut gives the arrays of all members simulated, to the bit, with two simulations; where
    the extremes differ, all are simulated."""
    from robomorph.identification.stiction import alike_or_each, mixed_horizon

    y, u, _, bb, est, held = fitted
    mix, space = FrictionMixture(bb.ident, 9), bb.ident.space
    simulated = {"alike": 0, "apart": 0}
    for b in [b for b in range(len(y)) if held[b].any()]:
        for params in (est[b], bb.catalogue(y[b, 0, 7:])):
            members = mix.candidates(params, held[b])
            problem = ContextProblem(bb.ident, params, y[b, :, 7:], u[b], np.zeros(7))
            count = []

            def simulate(rows):
                count.append(len(rows))
                return problem.joint_error(space.to_unit(members[rows][:, space.index])), problem.last_qvel_end.copy()

            err, end = alike_or_each(simulate, len(members))
            every = problem.joint_error(space.to_unit(members[:, space.index]))
            np.testing.assert_array_equal(err, every)
            np.testing.assert_array_equal(end, problem.last_qvel_end)
            simulated["alike" if sum(count) == 2 else "apart"] += 1
            # The horizons: the mixture's weighted mean as if every member had been simulated.
            w = np.full(len(members), 1 / len(members))
            q, tq = y[b:b + 1, :, 7:], u[b:b + 1]
            mean, var = mixed_horizon(bb, [(members, w, end)], q, tq, tq[:, -20:], np.zeros((1, 7)), y[b:b + 1, -1, 3:7])
            each = bb.simulate(members, np.repeat(q, len(members), 0), np.repeat(tq, len(members), 0),
                               np.repeat(tq[:, -20:], len(members), 0), np.zeros((len(members), 7)),
                               np.repeat(y[b:b + 1, -1, 3:7], len(members), 0), end)
            expected = np.tensordot(w, each, axes=1)
            np.testing.assert_allclose(mean[0], expected, rtol=0, atol=1e-12)
            np.testing.assert_allclose(var[0], np.tensordot(w, (each - expected) ** 2, axes=1), rtol=0, atol=1e-12)
    assert simulated["alike"] and simulated["apart"]  # both cases met: the shortcut and the whole mixture
