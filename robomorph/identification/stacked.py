"""Inverse dynamics of many states in one MuJoCo call: copies of the arm side by side in one model.

The regression (:mod:`robomorph.identification.regressor`) needs the torque at every state of a context, a
few times per fit. One ``mj_inverse`` per state pays the binding's call and the copies in and
out, about two thirds of its time (measured on the lean Panda: 5.2 µs per call from Python, 2.0 µs
per state with 50 copies in one model). So the model here holds ``copies`` independent copies of
the lean arm (no contacts: they never touch), and a call sets a state per copy. Each copy's
dynamics and constraint rows are its own (inverse dynamics solves no coupled problem: a soft
constraint's force follows from its own row), and each copy's constants (``dof_invweight0``, which
sets the friction constraints' softness) are the single arm's, so every copy's torque is the
single arm's at its state (to rounding: the Jacobians are sparse here, block diagonal, which keeps
the cost linear in the copies). The tests hold it to one call per state on the single arm.
"""

from __future__ import annotations

import mujoco
import numpy as np

# Copies of the arm in one model: past ~50 the cost per state stops falling (2.0 µs at 50, 3.2 at 22).
COPIES = 50
# What :meth:`robomorph.sim.randomize.Randomizer.apply` writes, by the size it is indexed with.
_BODY_FIELDS = ("body_mass", "body_inertia", "body_ipos")
_DOF_FIELDS = ("dof_damping", "dof_armature", "dof_frictionloss")
_JOINT_FIELDS = ("jnt_stiffness",)
_QPOS_FIELDS = ("qpos_spring",)
# As plain integers: numpy compares an array with MuJoCo's enum objects element by element in Python (0.5 ms).
_FRICTION_ROW = int(mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF)
_SATURATED = int(mujoco.mjtConstraintState.mjCNSTRSTATE_LINEARPOS), int(mujoco.mjtConstraintState.mjCNSTRSTATE_LINEARNEG)


class StackedInverse:
    """``copies`` copies of one lean arm for batched inverse dynamics (not thread-safe).

    Args:
        spec_of: makes the single arm's spec (:func:`robomorph.identification.identify.lean_spec`), once per copy.
        single: the compiled single arm, whose options (gravity, flags) the copies take.
        nj: the arm's actuated joints (the first ``nj`` of each copy's degrees of freedom).
    """

    def __init__(self, spec_of, single: mujoco.MjModel, nj: int, copies: int = COPIES):
        spec = spec_of()
        for k in range(1, copies):
            spec.attach(spec_of(), frame=spec.worldbody.add_frame(), prefix=f"copy{k}_")
        self.model = spec.compile()
        self.model.opt.jacobian = mujoco.mjtJacobian.mjJAC_SPARSE
        self.data = mujoco.MjData(self.model)
        self.copies, self.nj = int(copies), int(nj)
        self.nq, self.nv, self.nb = single.nq, single.nv, single.nbody - 1
        if (self.model.nq, self.model.nv, self.model.nbody) != (copies * self.nq, copies * self.nv,
                                                                 1 + copies * self.nb):
            raise RuntimeError("the stacked arm's copies do not lie in contiguous blocks: MuJoCo's order changed")

    def load(self, single: mujoco.MjModel) -> None:
        """Every copy takes the single arm's parameters (as the randomizer wrote them) and options."""
        m, k = self.model, self.copies
        m.opt.disableflags, m.opt.enableflags, m.opt.timestep = single.opt.disableflags, single.opt.enableflags, \
            single.opt.timestep
        m.opt.gravity[:] = single.opt.gravity
        for name in _BODY_FIELDS:
            getattr(m, name)[1:] = np.tile(getattr(single, name)[1:], (k,) + (1,) * (getattr(single, name).ndim - 1))
        for name in _DOF_FIELDS + _JOINT_FIELDS + _QPOS_FIELDS:
            getattr(m, name)[:] = np.tile(getattr(single, name), k)

    def run(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, carried: np.ndarray, bodies: bool = False,
            friction: bool = False) -> tuple:
        """(T, nj) joint torques at each state (gravity as the single arm has it); with ``bodies``, (T, nj, nbody)
        each body's share of them (:func:`_shares`; else None); with ``friction``, (T, nj) each joint's
        friction-loss column (:func:`_signs`; else, or where unreadable, None). ``copies`` states per call."""
        m, d, k, nj = self.model, self.data, self.copies, self.nj
        t_all = len(q)
        out = np.empty((t_all, nj))
        cdof = np.zeros((t_all, nj, 6)) if bodies else None
        cfrc = np.zeros((t_all, self.nb + 1, 6)) if bodies else None
        states, readable = np.zeros((t_all, nj), dtype=np.int32), friction
        qpos, qvel, qacc = (x.reshape(k, -1)[:, :nj] for x in (d.qpos, d.qvel, d.qacc))
        torque = d.qfrc_inverse.reshape(k, -1)
        for s in range(0, t_all, k):
            n = min(k, t_all - s)
            qpos[:n], qvel[:n], qacc[:n] = q[s:s + n], v[s:s + n], a[s:s + n]
            mujoco.mj_inverse(m, d)
            out[s:s + n] = torque[:n, :nj]
            if readable:
                readable = _read_friction(d, states[s:s + n], n, self.nv, nj)
            if bodies:
                mujoco.mj_rnePostConstraint(m, d)  # fills cfrc_int from the given accelerations
                cdof[s:s + n] = d.cdof.reshape(k, self.nv, 6)[:n, :nj]
                cfrc[s:s + n, 1:] = d.cfrc_int[1:].reshape(k, self.nb, 6)[:n]
        shares = _shares(self.nb + 1, self.model.body_parentid[:self.nb + 1], cdof, cfrc, carried) if bodies else None
        return out, shares, (_signs(states) if readable else None)


def _read_friction(d: mujoco.MjData, states: np.ndarray, n: int, nv: int, nj: int) -> bool:
    """Writes each copy's friction-loss constraint states into ``states`` (n, nj) (left 0, satisfied, where a
    joint has no such row); False where the rows cannot be read (other constraints lead them: MuJoCo's order)."""
    nf = int(d.nf)
    if d.ne or not nf or np.any(d.efc_type[:nf] != _FRICTION_ROW):
        return False  # as no rows at all: the caller bumps instead
    copy, joint = np.divmod(d.efc_id[:nf], nv)
    if np.any(joint >= nj):
        return False
    keep = copy < n  # the copies past the last state hold stale states
    states[copy[keep], joint[keep]] = d.efc_state[:nf][keep]
    return True


def _signs(states: np.ndarray) -> np.ndarray:
    """(T, nj) the torque's change per unit of each joint's friction loss: its constraint saturated (Coulomb:
    +1 or -1 with the force's side), or not (0: the force does not depend on it). The derivative that a bumped
    pass approximates (equal on 5,542 of 5,544 samples of four held-out contexts, the others within 1 % of the bend)."""
    return (states == _SATURATED[0]) * 1.0 - (states == _SATURATED[1])  # a joint without a row: 0, satisfied


def carried_bodies(model: mujoco.MjModel, nj: int) -> np.ndarray:
    """(nj, nbody): 1 where joint j carries body i (i is j's body or hangs below it)."""
    carried = np.zeros((nj, model.nbody))
    for i in range(1, model.nbody):
        b = i
        while b > 0:
            carried[model.dof_bodyid[:nj] == b, i] = 1.0
            b = model.body_parentid[b]
    return carried


def _shares(nbody: int, parents: np.ndarray, cdof: np.ndarray, cfrc: np.ndarray, carried: np.ndarray) -> np.ndarray:
    """(T, nj, nbody) each body's share of each joint's torque, from the joints' motion axes
    ``cdof`` (T, nj, 6) and ``cfrc_int`` (T, nbody, 6), which sums a body's subtree.

    A body's share is the power pairing of each joint's motion axis with the force that moving
    the body alone takes (its inertia times its acceleration, gravity included, plus the
    gyroscopic term: its ``cfrc_int`` less its children's), over the bodies the joint carries.
    It leaves out one thing a pass per mass sees: the discrete step's implicit damping lets the
    friction losses' holding force depend on the inertia (measured: up to 4 % of a column on the
    hand, none without the discrete inverse)."""
    own = cfrc.copy()
    for i in range(1, nbody):
        if parents[i] > 0:
            own[:, parents[i]] -= cfrc[:, i]
    return np.einsum("tjk,tik->tji", cdof, own) * carried[None]
