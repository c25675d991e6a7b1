"""The hybrid's batched work gives what its window-by-window form gives: threads and batches change the time, not the answer."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.model.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def test_threaded_regressions_equal_one_solver_window_by_window(hybrid_ckpt, command_store, monkeypatch):
    from robomorph.model import hybrid as hybrid_module
    from robomorph.model.predictor import Predictor

    uc, yc, _, _, _, _ = _windows(command_store, n=5)
    results = []
    for threads in (1, 2):
        monkeypatch.setattr(hybrid_module, "REGRESSION_THREADS", threads)
        hyb = Predictor.from_checkpoint(hybrid_ckpt).hybrid()
        hyb.members = 1  # the regression's estimate itself
        params = hyb.identify(torch.as_tensor(uc), torch.as_tensor(yc), "regression", at_rest=True)
        results.append((params, np.stack(hyb._covs), hyb._held.copy(), len(hyb._regressors)))
        hyb.close()
    (p1, c1, h1, n1), (p2, c2, h2, n2) = results
    assert (n1, n2) == (1, 2)
    np.testing.assert_array_equal(p1, p2)
    np.testing.assert_array_equal(c1, c2)
    np.testing.assert_array_equal(h1, h2)
    assert not np.allclose(p1[0], p1[1])  # different robots: a mix-up of windows would show


def test_a_regression_error_in_a_thread_reaches_the_caller(hybrid_ckpt, command_store, monkeypatch):
    from robomorph.model import hybrid as hybrid_module
    from robomorph.model.predictor import Predictor

    uc, yc, _, _, _, _ = _windows(command_store, n=4)
    monkeypatch.setattr(hybrid_module, "REGRESSION_THREADS", 2)
    hyb = Predictor.from_checkpoint(hybrid_ckpt).hybrid()
    q = yc[..., 7:].astype(np.float64)
    q[3, 2:] = np.nan  # the last window (the second thread's) cannot be solved
    with pytest.raises(np.linalg.LinAlgError):  # (the Predictor refuses non-finite inputs before this)
        hybrid_module._regress(hyb, np.zeros((4, 1)), q, uc.astype(np.float64))
    hyb.close()


def test_batched_context_velocities_equal_the_fits_rollouts(command_store):
    """The velocity each horizon starts from is the end of its context simulated from the first
    sample: computed for all windows in one threaded batch, it equals the identification's own
    rollout of each context (:class:`robomorph.sim.identify._Problem`)."""
    from robomorph.sim.backbone import PhysicsBackbone, parameter_layout
    from robomorph.sim.identify import _Problem

    uc, yc, _, _, params, attrs = _windows(command_store, n=4)
    q = yc[..., 7:].astype(np.float64)
    qvel0 = np.zeros((len(q), 7))
    with PhysicsBackbone(parameter_layout(attrs), "command", nthread=2) as bb:
        batched = bb.context_velocity(params, q, uc.astype(np.float64), qvel0)
        space = bb.ident.space
        for b in range(len(q)):
            problem = _Problem(bb.ident, params[b], q[b], uc[b].astype(np.float64), qvel0[b])
            problem.joint_error(space.to_unit(params[b][space.index])[None])
            np.testing.assert_allclose(batched[b], problem.last_qvel_end[0], rtol=0, atol=1e-12)
    assert np.abs(batched).max() > 1e-3  # the robots move: a zero velocity would not pass
