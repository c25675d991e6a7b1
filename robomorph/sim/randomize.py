"""Domain randomization of the Panda: sample physical parameters, write them into a model.

Values are absolute and drawn around nominal values stored once from a freshly compiled
model, so applying parameters to a model copy many times never compounds. Every sampled
value has a name and is recorded in the dataset's ``params``.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.config import check_range
from robomorph.sim import panda

_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class RandomizationConfig:
    """Ranges of the randomized parameters (paper values as defaults).

    Attributes:
        mass_pct: link masses scaled by U(1 - p/100, 1 + p/100); inertia scales with mass.
        com_offset: each centre-of-mass coordinate moved by U(-c, c) metres (the paper
            claims this; its code had it commented out).
        damping: joint damping drawn from this absolute range [N m s / rad].
        stiffness: joint stiffness [N m / rad] toward the initial pose.
        armature: reflected rotor inertia [kg m^2].
        frictionloss_scale: dry friction scaled from the nominal per-joint value.
        init_q0_fraction: joint 0 starts at U(a, b) * sign * U(lower, upper) (paper's code).
        init_spread: joints 1..6 start at mid-range + U(-s, s) rad.
    """

    mass_pct: float = 10.0
    com_offset: float = 0.01
    damping: tuple[float, float] = (5.0, 10.0)
    stiffness: tuple[float, float] = (0.01, 0.05)
    armature: tuple[float, float] = (0.05, 0.15)
    frictionloss_scale: tuple[float, float] = (0.5, 1.5)
    init_q0_fraction: tuple[float, float] = (0.2, 0.8)
    init_spread: float = 0.25

    def __post_init__(self):
        if not 0 <= self.mass_pct < 100:
            raise ValueError(f"randomization.mass_pct must be in [0, 100), got {self.mass_pct}")
        if self.com_offset < 0 or self.init_spread < 0:
            raise ValueError("randomization.com_offset and init_spread must be >= 0")
        for name in ("damping", "stiffness", "armature", "frictionloss_scale", "init_q0_fraction"):
            check_range(f"randomization.{name}", getattr(self, name))
        if self.init_q0_fraction[1] > 1:
            raise ValueError("randomization.init_q0_fraction must lie within [0, 1]")


def param_names() -> list[str]:
    """Names of the recorded parameters, in the order of :func:`Randomizer.sample`."""
    bodies = panda.LINK_BODIES
    names = [f"mass_{b}" for b in bodies]
    names += [f"com_{b}_{a}" for b in bodies for a in _AXES]
    for prefix in ("damping", "stiffness", "armature", "frictionloss", "qinit"):
        names += [f"{prefix}_q{j}" for j in range(panda.N_JOINT)]
    return names


class Randomizer:
    """Samples parameter vectors and applies them to copies of one compiled model."""

    def __init__(self, model: mujoco.MjModel, cfg: RandomizationConfig):
        self.cfg = cfg
        self.index = panda.PandaIndex.of(model)
        ids, nj = self.index.body_ids, panda.N_JOINT
        self.mass0 = model.body_mass[ids].copy()
        self.inertia0 = model.body_inertia[ids].copy()
        self.ipos0 = model.body_ipos[ids].copy()
        self.friction0 = model.dof_frictionloss[:nj].copy()
        self.names = param_names()

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Draws one parameter vector (float64, named by :func:`param_names`)."""
        c, nj, nb = self.cfg, panda.N_JOINT, len(self.mass0)
        scale = rng.uniform(1 - c.mass_pct / 100, 1 + c.mass_pct / 100, nb)
        com = self.ipos0 + rng.uniform(-c.com_offset, c.com_offset, (nb, 3))
        damping = rng.uniform(*c.damping, nj)
        stiffness = rng.uniform(*c.stiffness, nj)
        armature = rng.uniform(*c.armature, nj)
        friction = self.friction0 * rng.uniform(*c.frictionloss_scale, nj)
        qinit = self._initial_joints(rng)
        return np.concatenate(
            [self.mass0 * scale, com.ravel(), damping, stiffness, armature, friction, qinit]
        )

    def _initial_joints(self, rng: np.random.Generator) -> np.ndarray:
        c, (lo, hi) = self.cfg, self.index.joint_range.T
        q = (lo + hi) / 2 + rng.uniform(-c.init_spread, c.init_spread, panda.N_JOINT)
        sign = rng.choice([-1.0, 1.0])
        q[0] = rng.uniform(*c.init_q0_fraction) * sign * rng.uniform(lo[0], hi[0])
        return q

    def split(self, params: np.ndarray) -> dict[str, np.ndarray]:
        """Views of a parameter vector by kind."""
        nb, nj = len(self.mass0), panda.N_JOINT
        out, i = {}, 0
        for key, size in (("mass", nb), ("com", 3 * nb), ("damping", nj), ("stiffness", nj),
                          ("armature", nj), ("frictionloss", nj), ("qinit", nj)):
            out[key] = params[i:i + size]
            i += size
        out["com"] = out["com"].reshape(nb, 3)
        return out

    def apply(self, model: mujoco.MjModel, params: np.ndarray) -> None:
        """Writes absolute values into ``model`` (any copy of the nominal model)."""
        p, ids, nj = self.split(params), self.index.body_ids, panda.N_JOINT
        model.body_mass[ids] = p["mass"]
        model.body_inertia[ids] = self.inertia0 * (p["mass"] / self.mass0)[:, None]
        model.body_ipos[ids] = p["com"]
        model.dof_damping[:nj] = p["damping"]
        model.jnt_stiffness[:nj] = p["stiffness"]
        model.dof_armature[:nj] = p["armature"]
        model.dof_frictionloss[:nj] = p["frictionloss"]
        # The spring pulls toward where the robot started, not a fixed home pose.
        model.qpos_spring[:nj] = p["qinit"]
