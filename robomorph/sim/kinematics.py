"""Forward kinematics of an arm's end-effector site, vectorized over any number of joint rows.

Real arms often log only joint angles and torques. A model trained in simulation predicts
the simulator's ``y`` (EE x y z [m], EE quaternion X Y Z W, q0..q6 [rad]); :func:`ee_pose`
computes the first seven channels from the joint angles with the nominal (not randomized)
model, so a real log can be put in the same layout (``robomorph ingest --layout panda``).
The physics backbone (:mod:`robomorph.identification.backbone`) turns every simulated horizon into
those channels the same way.

:class:`SiteKinematics` composes the site's chain of bodies as ``mj_kinematics`` does
(each body's offset in its parent, then its hinge rotated about its anchor), as numpy
operations over all rows at once: one ``mj_kinematics`` call per row costs microseconds of
Python each, which for 256 candidate horizons of a model-predictive controller is most of
what is not physics. The quaternion takes the sign ``mju_mat2Quat`` gives the site's
rotation matrix, so the result equals the per-row MuJoCo path to rounding
(``tests/sim/test_kinematics.py``). A chain with other joints than hinges falls back to it.
"""

from __future__ import annotations

import mujoco
import numpy as np

from robomorph.sim import panda
from robomorph.sim.filters import continuous_quaternion


def _quat2mat(q: np.ndarray) -> np.ndarray:
    """(4,) unit quaternion (w x y z) -> (3, 3) rotation matrix."""
    m = np.empty(9)
    mujoco.mju_quat2Mat(m, np.asarray(q, dtype=np.float64))
    return m.reshape(3, 3)


def _mat2quat(r: np.ndarray) -> np.ndarray:
    """(3, 3, ...) rotation matrices (the rows last) -> (..., 4) quaternions (w x y z), branch for branch
    ``mju_mat2Quat``: from the trace where it is positive, else from the largest diagonal
    entry, whose component is then positive (so the signs are MuJoCo's)."""
    r00, r11, r22 = r[0, 0], r[1, 1], r[2, 2]
    d21, d02, d10 = r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]
    s01, s02, s12 = r[0, 1] + r[1, 0], r[0, 2] + r[2, 0], r[1, 2] + r[2, 1]
    trace = r00 + r11 + r22
    pick = np.where(trace > 0, 0, 1 + np.argmax(np.stack([r00, r11, r22]), axis=0))
    big = 0.5 * np.sqrt(np.choose(pick, [1 + trace, 1 + r00 - r11 - r22, 1 - r00 + r11 - r22, 1 - r00 - r11 + r22]))
    inv = 0.25 / big
    # Component k of branch b: its leading component where k == b, else a difference or sum over 4 big.
    w = np.choose(pick, [big, d21 * inv, d02 * inv, d10 * inv])
    x = np.choose(pick, [d21 * inv, big, s01 * inv, s02 * inv])
    y = np.choose(pick, [d02 * inv, s01 * inv, big, s12 * inv])
    z = np.choose(pick, [d10 * inv, s02 * inv, s12 * inv, big])
    out = np.stack([w, x, y, z], axis=-1)
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation matrix whose third column is the unit ``axis`` (a frame where it is z)."""
    z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


class SiteKinematics:
    """Position and orientation of one site for rows of joint angles (reusable, thread-safe).

    Args:
        model: the compiled arm (its catalogue geometry: link geometry is not randomized).
        site: the site's name.
    """

    def __init__(self, model: mujoco.MjModel, site: str = "ee"):
        self.model, self.site = model, model.site(site).id
        chain, body = [], int(model.site_bodyid[self.site])
        while body > 0:
            chain.append(body)
            body = int(model.body_parentid[body])
        # Each hinge turns about z of its own frame P (its axis as z), so a turn is two column
        # updates; P's inverse is folded into the next offset and rotation: a chain of (offset,
        # fixed rotation, hinge (qpos address, anchor in P, qpos0) or None), from the world outwards.
        self._chain, self.vectorized, pending = [], True, np.eye(3)
        for b in reversed(chain):
            adr, num = int(model.body_jntadr[b]), int(model.body_jntnum[b])
            if num > 1 or (num == 1 and model.jnt_type[adr] != mujoco.mjtJoint.mjJNT_HINGE):
                self.vectorized = False
            offset, fixed = pending.T @ model.body_pos[b], pending.T @ _quat2mat(model.body_quat[b])
            hinge, pending = None, np.eye(3)
            if num == 1:
                pending = _to_z(model.jnt_axis[adr])
                qadr = int(model.jnt_qposadr[adr])
                hinge = (qadr, pending.T @ model.jnt_pos[adr], float(model.qpos0[qadr]))
                fixed = fixed @ pending
            self._chain.append((offset, fixed, hinge))
        # The links between hinges compose to one offset and rotation each (what is fixed needs no row-wise
        # product): steps of (offset, rotation, hinge) and a last (offset, rotation) to the site.
        offset, rot, self._steps = np.zeros(3), np.eye(3), []
        for link_offset, fixed, hinge in self._chain:
            offset, rot = offset + rot @ link_offset, rot @ fixed
            if hinge is not None:
                self._steps.append((offset, rot, hinge))
                offset, rot = np.zeros(3), np.eye(3)
        self._tail = (offset + rot @ (pending.T @ model.site_pos[self.site]),
                      rot @ pending.T @ _quat2mat(model.site_quat[self.site]))
        self._data = None

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., nq') joint angles (the first joints of ``qpos``) -> (..., 3) position and (..., 4)
        quaternion (w x y z, ``mju_mat2Quat``'s sign per row) of the site."""
        q = np.asarray(q, dtype=np.float64)
        if not self.vectorized:
            return self._per_row(q)
        lead, angles = q.shape[:-1], q.reshape(-1, q.shape[-1]).T
        # Rotation (3, 3, N) and position (3, N): the rows last, so that each product with a
        # constant matrix is a few contiguous vector operations. Before the first hinge both are constants.
        n = angles.shape[1]
        pos, rot = np.zeros((3, 1)), np.eye(3)[..., None]
        for offset, fixed, (qadr, anchor, ref) in self._steps:
            pos = pos + np.einsum("ijn,j->in", rot, offset)
            rot = np.einsum("ijn,jk->ikn", rot, fixed)
            c, s = np.cos(angles[qadr] - ref), np.sin(angles[qadr] - ref)
            if anchor[:2].any():  # a turn about the anchor, not the frame's origin, moves the origin
                pos = pos + rot[:, 0] * (anchor[0] * (1 - c) + anchor[1] * s) \
                    + rot[:, 1] * (anchor[1] * (1 - c) - anchor[0] * s)
            turned = np.empty((3, 3, n))
            turned[:, 0] = c * rot[:, 0] + s * rot[:, 1]
            turned[:, 1] = c * rot[:, 1] - s * rot[:, 0]
            turned[:, 2] = rot[:, 2]
            rot = turned
        offset, fixed = self._tail
        pos = np.broadcast_to(pos + np.einsum("ijn,j->in", rot, offset), (3, n))
        quat = _mat2quat(np.broadcast_to(np.einsum("ijn,jk->ikn", rot, fixed), (3, 3, n)))
        return pos.T.reshape(lead + (3,)), quat.reshape(lead + (4,))

    def _per_row(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """MuJoCo's own ``mj_kinematics``, one row at a time."""
        if self._data is None:
            self._data = mujoco.MjData(self.model)
        d, rows = self._data, q.reshape(-1, q.shape[-1])
        pos, quat = np.empty((len(rows), 3)), np.empty((len(rows), 4))
        for t, qt in enumerate(rows):
            d.qpos[:len(qt)] = qt
            mujoco.mj_kinematics(self.model, d)
            pos[t] = d.site_xpos[self.site]
            mujoco.mju_mat2Quat(quat[t], d.site_xmat[self.site])
        return pos.reshape(q.shape[:-1] + (3,)), quat.reshape(q.shape[:-1] + (4,))


def ee_pose(q: np.ndarray, model: mujoco.MjModel | None = None) -> np.ndarray:
    """End-effector pose of the ``ee`` site for each row of joint angles.

    Args:
        q: (T, n) joint angles [rad], the model's joints in order (the Panda's 7 by default).
        model: a compiled arm with an ``ee`` site (default: the catalogue Panda,
            :func:`panda.build_model`).

    Returns:
        (T, 7) float64: EE x y z [m] and the EE quaternion X Y Z W, signs kept continuous
        over time as the simulator's recordings keep them.
    """
    q = np.asarray(q, dtype=np.float64)
    n = panda.N_JOINT if model is None else model.nq
    if q.ndim != 2 or q.shape[1] != n:
        raise ValueError(f"joint angles must have shape (T, {n}), got {q.shape}")
    pos, quat_wxyz = SiteKinematics(model or panda.build_model())(q)
    quat_wxyz = continuous_quaternion(quat_wxyz)
    return np.concatenate([pos, quat_wxyz[:, [1, 2, 3, 0]]], axis=1)
