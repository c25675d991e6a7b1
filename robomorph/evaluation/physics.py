"""The ``nominal_physics`` baseline: the catalogue arm simulated from the end of the context.

What knowing the robot's catalogue model already gives, without learning anything: the
un-randomized arm of the store (any arm of :mod:`robomorph.sim.arms`; nominal masses and
centres of mass, damping, stiffness and armature
at the middle of the recipe's ranges, nominal friction) starts from the last context
state and is driven by the recorded torques. The joint velocity at that state is not
in ``y``; it is estimated from the context positions (a cubic through the last samples),
so even on an un-randomized store the prediction differs from the truth by what that
estimate misses.

Two input formulations (``inputs``):

* ``total``: the recorded ``u`` is the full torque at the joints at the start of each
  frame. When the recipe compensated gravity through the actuators (``true_model``), that
  compensation followed the state through the frame's physics substeps; the baseline does
  the same with the simulated model's gravity (command = u - g(q) at the frame start), so
  on an un-randomized robot it reproduces the recorded torques. Otherwise ``u`` is held
  over the frame as recorded. g(q) is paid at the *recorded* state, so any deviation
  feels gravity uncompensated and grows (about tenfold every 57 steps): no simulation
  follows this formulation far.
* ``command``: ``u`` is the command ``u_cmd``, simulated on an arm that compensates its own
  gravity at its current state, as the generator does: ``true_model`` through the
  actuators (the simulated model's own g(q)), ``nominal_model`` by adding the catalogue
  robot's g(q) at each frame start, ``none`` not at all. Deviations do not grow.
"""

from __future__ import annotations

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.core.velocity import estimate_velocity


class NotApplicable(RoboMorphError, ValueError):
    """The baseline cannot run on this store; the message says why."""


def check_params(attrs: dict) -> None:
    """Raises :class:`NotApplicable` unless the store records the randomizer's parameters."""
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.sim.randomize import param_names  # noqa: PLC0415

    arm = arms.of_store(attrs)
    if arm is None or list(attrs.get("param_names", [])) != param_names(arm.name):
        raise NotApplicable("needs the per-robot parameters the generator records (params of this store "
                            "are missing or named differently)")


def recipe_of(attrs: dict):
    """The recipe a store's robot is simulated with: a simulated store's generator config, or
    for a real log of a registered arm (``ingest --layout ARM``) the catalogue arm at the
    log's rate with no gravity compensation of its own (the logged torque is the total one,
    gravity included)."""
    from robomorph.core.config import from_dict  # noqa: PLC0415
    from robomorph.sim.recipe import Recipe  # noqa: PLC0415

    if attrs.get("task") == "ingested":
        return Recipe(robot=str(attrs["arm"]), dt=float(attrs["dt"]), gravity_compensation="none")
    return from_dict(Recipe, attrs["config"], "store config")


class NominalPhysics:
    """Callable ``(u_ctx, y_ctx, u_query) -> y_query`` for stores of a simulated arm, and for
    real logs of a registered arm (ingested with ``--layout ARM``: driven by the logged total
    torque).

    Args:
        attrs: the store's attributes (domain, channel names and generator config).
        inputs: ``total`` (torques given are ``u``) or ``command`` (they are ``u_cmd``).

    Raises:
        NotApplicable: the store is neither a simulated store of a registered arm nor a real
            log in a registered arm's layout (other domains, another channel layout).
    """

    def __init__(self, attrs: dict, inputs: str = "total"):
        import mujoco  # noqa: PLC0415

        from robomorph.core.inputs import check_inputs  # noqa: PLC0415  (MuJoCo only when used)
        from robomorph.sim import arms  # noqa: PLC0415
        from robomorph.sim.episode import NominalGravity  # noqa: PLC0415
        from robomorph.sim.randomize import Randomizer  # noqa: PLC0415

        logged = attrs.get("task") == "ingested"
        arm = arms.ARMS.get(str(attrs.get("arm"))) if logged else arms.of_store(attrs)
        if arm is None or not isinstance(attrs.get("config"), dict):
            raise NotApplicable(f"needs a store of one of the arms {arms.names()}: simulated with its generator config, "
                                f"or a real log ingested with --layout ARM (this store's domain is "
                                f"{attrs.get('domain')!r})")
        if tuple(attrs.get("u_names", ())) != arm.u_names or tuple(attrs.get("y_names", ())) != arm.y_names:
            n = arm.n_joint
            raise NotApplicable(f"needs the {arm.name} channel layout (u = tau0..tau{n - 1}, "
                                f"y = EE pose and q0..q{n - 1})")
        recipe = self.recipe = recipe_of(attrs)
        if recipe.robot != arm.name:
            raise NotApplicable(f"the store's domain {arm.name!r} and its recipe's robot {recipe.robot!r} differ")
        self.dt, self.substeps = float(recipe.dt), int(recipe.substeps)
        self.inputs = check_inputs(inputs)
        self.gravity_in_actuators = recipe.gravity_compensation == "true_model"
        # nominal_model: the arm's controller adds the catalogue robot's g(q) to the command.
        self._catalogue_gravity = (NominalGravity(recipe) if inputs == "command"
                                   and recipe.gravity_compensation == "nominal_model" else None)
        self.model = arm.build_model(recipe.substeps, recipe.dt, self.gravity_in_actuators)
        self.data = mujoco.MjData(self.model)
        self._randomizer = Randomizer(self.model, recipe.randomization, arm.name)
        self.n_joint = arm.n_joint
        self.joints = slice(7, 7 + arm.n_joint)  # the columns of y holding the joint angles
        self.quaternion = slice(3, 7)  # the columns of y holding the end effector's orientation

    def params(self, qinit: np.ndarray) -> np.ndarray:
        """The nominal parameter vector (in ``params`` order) with the spring anchored at ``qinit``."""
        return self._randomizer.catalogue(qinit)

    def __call__(self, u_ctx: np.ndarray, y_ctx: np.ndarray, u_query: np.ndarray,
                 params: np.ndarray | None = None) -> np.ndarray:
        """Predicts ``y_query``; with ``params`` (B, P), each robot's own stored parameters
        replace the nominal ones (the ``true_physics`` ceiling)."""
        q_ctx = y_ctx[..., self.joints].astype(np.float64)
        qvel0 = estimate_velocity(q_ctx, self.dt)
        # Frames c-1 .. c+H-1: from the last context state, under u[c-1] then the query.
        torque = np.concatenate([u_ctx[:, -1:], u_query], axis=1).astype(np.float64)
        return np.stack([self._one(q_ctx[b], qvel0[b], torque[b], y_ctx[b, -1, self.quaternion],
                                   None if params is None else np.asarray(params[b], dtype=np.float64))
                         for b in range(len(torque))])

    def rollout(self, torque: np.ndarray, qpos0: np.ndarray, qvel0: np.ndarray | None = None,
                params: np.ndarray | None = None) -> np.ndarray:
        """Simulates ``torque`` (T, n), in this baseline's formulation, from joint state
        ``(qpos0, qvel0)``; returns y (T, 7 + n) at the start of each frame (row 0: the start).

        ``params`` are the robot's own parameters (default: the catalogue robot with its
        springs anchored at ``qpos0``).
        """
        from robomorph.sim.closed_loop import simulate_closed_loop  # noqa: PLC0415
        from robomorph.sim.filters import to_outputs  # noqa: PLC0415

        self._randomizer.apply(self.model, self.params(qpos0) if params is None else params)
        sens = simulate_closed_loop(self.model, self.data, qpos0, len(torque), self.substeps,
                                    self._controller(np.asarray(torque, dtype=np.float64)), qvel0)
        return to_outputs(sens)[1]

    def _one(self, q_ctx: np.ndarray, qvel0: np.ndarray, torque: np.ndarray, quat_last: np.ndarray,
             params: np.ndarray | None) -> np.ndarray:
        # The stiffness springs pull toward where the robot started: the first context
        # sample when the context opens the trajectory (stiffness is small either way).
        if params is None:
            params = self.params(q_ctx[0])
        y = self.rollout(torque, q_ctx[-1], qvel0, params)  # row f: the start of frame c-1+f
        if np.dot(y[0, self.quaternion], quat_last) < 0:  # the context's sign convention
            y[:, self.quaternion] *= -1.0
        return y[1:]

    def _controller(self, torque: np.ndarray):
        """``(data, t) -> ctrl`` that applies ``torque`` in this baseline's formulation."""
        from robomorph.sim.closed_loop import formulation_controller  # noqa: PLC0415

        return formulation_controller(torque, self.inputs, self.gravity_in_actuators, self.n_joint,
                                      self._catalogue_gravity)
