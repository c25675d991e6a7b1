"""Domain randomization of an arm: sample physical parameters, write them into a model.

Values are absolute and drawn around nominal values stored once from a freshly compiled
model, so applying parameters to a model copy many times never compounds. Every sampled
value has a name and is recorded in the dataset's ``params``.

The ranges are the Panda's. Another arm (:mod:`robomorph.sim.arms`) draws the same way
around its own masses, centres of mass and friction, with the absolute joint ranges
(damping, stiffness, armature) scaled per joint by how much larger its joints are than the
Panda's (:attr:`Arm.joint_gain`), and its initial poses centred on its own home pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from robomorph.core.config import check_range
from robomorph.sim import arms, panda

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

    def widened(self, factor: float) -> "RandomizationConfig":
        """The physical ranges widened about their middles by ``factor`` (>= 1), kept physical
        (masses above 5 % of nominal, damping, stiffness, armature and friction scales >= 0).
        The initial poses are not physical parameters and keep their ranges."""
        if not factor >= 1:
            raise ValueError(f"a widening factor must be >= 1, got {factor}")
        if factor == 1:
            return self

        def wide(rng: tuple[float, float]) -> tuple[float, float]:
            mid, half = (rng[0] + rng[1]) / 2, (rng[1] - rng[0]) / 2 * factor
            return max(0.0, mid - half), mid + half

        return RandomizationConfig(
            mass_pct=min(self.mass_pct * factor, 95.0), com_offset=self.com_offset * factor,
            damping=wide(self.damping), stiffness=wide(self.stiffness), armature=wide(self.armature),
            frictionloss_scale=wide(self.frictionloss_scale), init_q0_fraction=self.init_q0_fraction,
            init_spread=self.init_spread)


def param_names(robot: str = arms.DEFAULT_ROBOT) -> list[str]:
    """Names of the recorded parameters of ``robot``, in the order of :func:`Randomizer.sample`."""
    arm = arms.get(robot)
    bodies = arm.link_bodies(None if robot == "panda" else arm.build_model())
    return _names(bodies, arm.n_joint)


def _names(bodies: tuple[str, ...], nj: int) -> list[str]:
    names = [f"mass_{b}" for b in bodies]
    names += [f"com_{b}_{a}" for b in bodies for a in _AXES]
    for prefix in ("damping", "stiffness", "armature", "frictionloss", "qinit"):
        names += [f"{prefix}_q{j}" for j in range(nj)]
    return names


class Randomizer:
    """Samples parameter vectors and applies them to copies of one compiled model.

    ``widen`` (the recipe's ``realism.widen``) draws from :meth:`RandomizationConfig.widened`
    ranges while ``cfg`` stays the box (and :meth:`catalogue` its middle): robots outside
    the bounds an identification reads from the recipe.
    """

    def __init__(self, model: mujoco.MjModel, cfg: RandomizationConfig, robot: str = arms.DEFAULT_ROBOT,
                 widen: float = 1.0):
        self.cfg = cfg
        self.draw_cfg = cfg.widened(widen)
        self.arm = arms.get(robot)
        self.nj = nj = self.arm.n_joint
        bodies = self.arm.link_bodies(model)
        self.index = panda.PandaIndex(np.array([model.body(b).id for b in bodies]),
                                      model.jnt_range[:nj].copy(), model.site("ee").id)
        ids = self.index.body_ids
        self.mass0 = model.body_mass[ids].copy()
        self.inertia0 = model.body_inertia[ids].copy()
        self.ipos0 = model.body_ipos[ids].copy()
        self.friction0 = model.dof_frictionloss[:nj].copy()
        self.gain = self.arm.joint_gain  # ones for the Panda: its draws are unchanged
        self.names = _names(bodies, nj)

    def catalogue(self, qinit: np.ndarray) -> np.ndarray:
        """The un-randomized robot's vector (in ``params`` order): nominal masses, centres of
        mass and friction loss (scaled by the middle of its range), damping, stiffness and
        armature at the middle of their ranges (scaled per joint as :meth:`sample` scales
        them), and the springs anchored at ``qinit``."""
        c = self.cfg
        mid = [np.full(self.nj, float(np.mean(getattr(c, k)))) * self.gain for k in ("damping", "stiffness", "armature")]
        return np.concatenate([self.mass0, self.ipos0.ravel(), *mid,
                               self.friction0 * float(np.mean(c.frictionloss_scale)), np.asarray(qinit, dtype=np.float64)])

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """Draws one parameter vector (float64, named by :func:`param_names`)."""
        c, nj, nb, gain = self.draw_cfg, self.nj, len(self.mass0), self.gain
        scale = rng.uniform(1 - c.mass_pct / 100, 1 + c.mass_pct / 100, nb)
        com = self.ipos0 + rng.uniform(-c.com_offset, c.com_offset, (nb, 3))
        damping = rng.uniform(*c.damping, nj) * gain
        stiffness = rng.uniform(*c.stiffness, nj) * gain
        armature = rng.uniform(*c.armature, nj) * gain
        friction = self.friction0 * rng.uniform(*c.frictionloss_scale, nj)
        qinit = self._initial_joints(rng)
        return np.concatenate(
            [self.mass0 * scale, com.ravel(), damping, stiffness, armature, friction, qinit]
        )

    def _initial_joints(self, rng: np.random.Generator) -> np.ndarray:
        c, (lo, hi) = self.cfg, self.index.joint_range.T
        home = self.arm.home
        # robosuite's home poses sit close to some limits: the centre is moved
        # arms.HOME_MARGIN inside, so the spread stays clear of the joint-limit filter.
        centre = arms.centre_pose(self.arm, self.index.joint_range)
        q = centre + rng.uniform(-c.init_spread, c.init_spread, self.nj)
        sign = rng.choice([-1.0, 1.0])
        if home is None:  # the Panda's (paper's) draw
            q[0] = rng.uniform(*c.init_q0_fraction) * sign * rng.uniform(lo[0], hi[0])
            return q
        # The base joint turns the whole arm about the vertical (the floor looks the same
        # from any angle): half its range (at most a quarter turn) leaves room to move.
        lo0, hi0 = max(lo[0], -np.pi) / 2, min(hi[0], np.pi) / 2
        q[0] = centre[0] + rng.uniform(*c.init_q0_fraction) * sign * rng.uniform(lo0, hi0)
        margin = 0.1  # rad inside the limits, away from the joint-limit filter
        return np.clip(q, lo + margin, hi - margin)

    def split(self, params: np.ndarray) -> dict[str, np.ndarray]:
        """Views of a parameter vector by kind."""
        nb, nj = len(self.mass0), self.nj
        out, i = {}, 0
        for key, size in (("mass", nb), ("com", 3 * nb), ("damping", nj), ("stiffness", nj),
                          ("armature", nj), ("frictionloss", nj), ("qinit", nj)):
            out[key] = params[i:i + size]
            i += size
        out["com"] = out["com"].reshape(nb, 3)
        return out

    def apply(self, model: mujoco.MjModel, params: np.ndarray) -> None:
        """Writes absolute values into ``model`` (any copy of the nominal model)."""
        p, ids, nj = self.split(params), self.index.body_ids, self.nj
        model.body_mass[ids] = p["mass"]
        model.body_inertia[ids] = self.inertia0 * (p["mass"] / self.mass0)[:, None]
        model.body_ipos[ids] = p["com"]
        model.dof_damping[:nj] = p["damping"]
        model.jnt_stiffness[:nj] = p["stiffness"]
        model.dof_armature[:nj] = p["armature"]
        model.dof_frictionloss[:nj] = p["frictionloss"]
        # The spring pulls toward where the robot started, not a fixed home pose.
        model.qpos_spring[:nj] = p["qinit"]
