"""The hybrid's batched work gives what its window-by-window form gives: batches change the time, not the answer."""

from __future__ import annotations

import numpy as np

from tests.inference.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def test_batched_context_velocities_equal_the_fits_rollouts(command_store):
    """The velocity each horizon starts from is the end of its context simulated from the first
    sample: computed for all windows in one threaded batch, it equals the identification's own
    rollout of each context (:class:`robomorph.identification.identify.ContextProblem`)."""
    from robomorph.identification.backbone import PhysicsBackbone, parameter_layout
    from robomorph.identification.identify import ContextProblem

    uc, yc, _, _, params, attrs = _windows(command_store, n=4)
    q = yc[..., 7:].astype(np.float64)
    qvel0 = np.zeros((len(q), 7))
    with PhysicsBackbone(parameter_layout(attrs), "command", nthread=2) as bb:
        batched = bb.context_velocity(params, q, uc.astype(np.float64), qvel0)
        space = bb.ident.space
        for b in range(len(q)):
            problem = ContextProblem(bb.ident, params[b], q[b], uc[b].astype(np.float64), qvel0[b])
            problem.joint_error(space.to_unit(params[b][space.index])[None])
            np.testing.assert_allclose(batched[b], problem.last_qvel_end[0], rtol=0, atol=1e-12)
    assert np.abs(batched).max() > 1e-3  # the robots move: a zero velocity would not pass


def test_the_observers_velocity_corrects_a_drifting_context_toward_the_true_one(command_store):
    """A robot that re-enacts its context has no residual, so the observer changes nothing; the
    catalogue robot drifts over the context, and the residual's velocity brings its end velocity
    toward the true robot's."""
    from robomorph.identification.backbone import PhysicsBackbone, parameter_layout

    uc, yc, _, _, params, attrs = _windows(command_store, n=4)
    q, u, rest = yc[..., 7:].astype(np.float64), uc.astype(np.float64), np.zeros((4, 7))
    with PhysicsBackbone(parameter_layout(attrs), "command") as bb:
        true_end = bb.context_velocity(params, q, u, rest)
        catalogue = np.stack([bb.catalogue(qq) for qq in q[:, 0]])
        plain = bb.context_velocity(catalogue, q, u, rest)
        bb.observe = True
        observed_true = bb.context_velocity(params, q, u, rest)
        observed = bb.context_velocity(catalogue, q, u, rest)
    np.testing.assert_allclose(observed_true, true_end, atol=1e-3)  # float32 storage of q
    before, after = np.abs(plain - true_end).mean(), np.abs(observed - true_end).mean()
    assert before > 1e-3 and after < 0.5 * before


def test_the_observer_reads_the_contexts_tail_and_agrees_with_the_whole_context(command_store):
    """Open-loop contexts simulate only the last OBSERVED_TAIL samples for the observer: what came
    before cannot change the velocity, which agrees with the whole context simulated (the path
    of formulations with state feedback, window by window) far within the correction itself."""
    from robomorph.identification.backbone import OBSERVED_TAIL, PhysicsBackbone, parameter_layout

    uc, yc, _, _, _, attrs = _windows(command_store, n=3)
    q, u, rest = yc[..., 7:].astype(np.float64), uc.astype(np.float64), np.zeros((3, 7))
    early = slice(0, q.shape[1] - OBSERVED_TAIL - 3)  # before the tail and its central difference
    assert early.stop > 2
    q2, u2 = q.copy(), u.copy()
    q2[:, early], u2[:, early] = q[::-1, early], -u[:, early]  # another past
    with PhysicsBackbone(parameter_layout(attrs), "command") as bb:
        catalogue = np.stack([bb.catalogue(qq) for qq in q[:, 0]])
        bb.observe = True
        tail = bb.context_velocity(catalogue, q, u, rest)
        np.testing.assert_array_equal(bb.context_velocity(catalogue, q2, u2, rest), tail)
        bb.open_loop = False  # the window-by-window path: the whole context
        whole = bb.context_velocity(catalogue, q, u, rest)
        bb.observe = False
        plain = bb.context_velocity(catalogue, q, u, rest)
    correction = np.abs(whole - plain).max()
    assert correction > 1e-3  # the observer acts
    assert np.abs(tail - whole).max() < 0.05 * correction, (np.abs(tail - whole).max(), correction)


def test_a_planners_candidates_tangent_linear_on_request(command_store, hybrid_ckpt):
    """``configure(candidates="tangent")`` answers many torque sequences on one context near the exact
    rollouts (:mod:`robomorph.identification.tangent`) and leaves windows of different contexts exact; an unknown
    setting is refused in one line that names the choices."""
    import pytest

    from robomorph.inference.predictor import PredictionError, Predictor

    uc, yc, uq, _, _, _ = _windows(command_store, n=2)
    k = 8
    rng = np.random.default_rng(0)
    cands = uq[:1, :20] + rng.normal(0.0, 0.3, (k, 20, 7)).astype(np.float32)
    pred = Predictor.from_checkpoint(hybrid_ckpt)
    pred.configure(mode="regression", members=1)
    exact, exact_windows = pred.simulate(np.repeat(uc[:1], k, 0), np.repeat(yc[:1], k, 0), cands), \
        pred.simulate(uc, yc, uq[:, :20])
    pred.configure(candidates="tangent")
    tangent, tangent_windows = pred.simulate(np.repeat(uc[:1], k, 0), np.repeat(yc[:1], k, 0), cands), \
        pred.simulate(uc, yc, uq[:, :20])
    assert 0 < np.abs(tangent - exact).max() < 2e-3
    np.testing.assert_array_equal(tangent_windows, exact_windows)
    with pytest.raises(PredictionError, match=r"candidates must be one of \['exact', 'tangent'\], got 'approximate'"):
        pred.configure(candidates="approximate")
