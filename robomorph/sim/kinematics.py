"""Forward kinematics of the catalogue Panda: joint angles -> end-effector pose, as ``y`` holds it.

Real arms often log only joint angles and torques. A model trained in simulation predicts
the simulator's ``y`` (EE x y z [m], EE quaternion X Y Z W, q0..q6 [rad]); this computes the
first seven channels from the joint angles with the nominal (not randomized) model, so a
real log can be put in the same layout (``robomorph ingest --layout panda``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from robomorph.sim import panda
from robomorph.sim.filters import continuous_quaternion


def ee_pose(q: np.ndarray, model: mujoco.MjModel | None = None) -> np.ndarray:
    """End-effector pose of the ``ee`` site for each row of joint angles.

    Args:
        q: (T, 7) joint angles [rad], joints 1..7 of the Panda in order.
        model: the compiled Panda (default: the catalogue model, :func:`panda.build_model`).

    Returns:
        (T, 7) float64: EE x y z [m] and the EE quaternion X Y Z W, signs kept continuous
        over time as the simulator's recordings keep them.
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != panda.N_JOINT:
        raise ValueError(f"joint angles must have shape (T, {panda.N_JOINT}), got {q.shape}")
    model = model or panda.build_model()
    data = mujoco.MjData(model)
    site = model.site("ee").id
    pos, quat_wxyz = np.empty((len(q), 3)), np.empty((len(q), 4))
    for t, angles in enumerate(q):
        data.qpos[:panda.N_JOINT] = angles
        mujoco.mj_kinematics(model, data)  # positions and orientations only: no dynamics needed
        pos[t] = data.site_xpos[site]
        mujoco.mju_mat2Quat(quat_wxyz[t], data.site_xmat[site])
    quat_wxyz = continuous_quaternion(quat_wxyz)
    return np.concatenate([pos, quat_wxyz[:, [1, 2, 3, 0]]], axis=1)
