"""The linear Kalman smoother (Rauch-Tung-Striebel) that each Gauss-Newton step of
:mod:`robomorph.identification.smoother` solves: a linearized state sequence with a diagonal measurement
of every state component at every step (weights zero where there is none)."""

from __future__ import annotations

import numpy as np


def _update(m: np.ndarray, p: np.ndarray, z: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A Kalman update by a measurement of every state component: values ``z``, weights (inverse
    variances) ``w`` (0: not measured)."""
    seen = w > 0
    if not seen.any():
        return m, p
    ps = p[:, seen]
    s = ps[seen] + np.diag(1.0 / w[seen])
    gain = np.linalg.solve(s, ps.T).T
    m = m + gain @ (z[seen] - m[seen])
    p = p - gain @ ps.T
    return m, 0.5 * (p + p.T)


def rts(x0, p0, nominal, jac, xbar, q, meas, weight):
    """The linear smoother of ``x_{k+1} = nominal_k + jac_k (x_k - xbar_k) + w_k`` (cov ``q``) with
    measurements ``meas[k]`` of x_k (k = 0..H) weighted by ``weight[k]``; returns means (H+1, n)
    and covariances (H+1, n, n)."""
    h, n = nominal.shape
    mf, pf = np.empty((h + 1, n)), np.empty((h + 1, n, n))
    mp, pp = np.empty((h + 1, n)), np.empty((h + 1, n, n))
    mf[0], pf[0] = _update(x0, p0, meas[0], weight[0])
    for k in range(h):
        mp[k + 1] = nominal[k] + jac[k] @ (mf[k] - xbar[k])
        pp[k + 1] = jac[k] @ pf[k] @ jac[k].T + q
        mf[k + 1], pf[k + 1] = _update(mp[k + 1], pp[k + 1], meas[k + 1], weight[k + 1])
    ms, ps = mf.copy(), pf.copy()
    for k in range(h - 1, -1, -1):
        g = np.linalg.solve(pp[k + 1], jac[k] @ pf[k]).T  # pf J' pp^-1 (both symmetric)
        ms[k] = mf[k] + g @ (ms[k + 1] - mp[k + 1])
        ps[k] = pf[k] + g @ (ps[k + 1] - pp[k + 1]) @ g.T
    return ms, ps
