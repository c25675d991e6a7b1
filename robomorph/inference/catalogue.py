"""A prediction with no training: the hybrid of a catalogue arm, with no network at all.

    from robomorph import Predictor
    pred = Predictor.from_arm("panda")                       # seconds; reads no checkpoint
    y_query, std = pred.simulate(u_ctx, y_ctx, u_query, return_std=True, at_rest=True)

In the command formulation the hybrid's default mode, ``regression``, identifies the robot
from the context by linear solves of its inverse dynamics, pulled toward the catalogue arm,
and simulates it over the horizon (:mod:`robomorph.inference.hybrid`): it never reads the network
of the checkpoint it comes from. So a Predictor built from the arm's catalogue model and a
generator recipe alone predicts exactly what a trained command-formulation hybrid predicts in
that mode, the same to the bit (a test checks it against a trained checkpoint). This module holds
what ``Predictor.from_arm`` (a classmethod of the Predictor, beside ``from_checkpoint``) builds it from:
the record (:func:`arm_record`), the stand-in for a network (:class:`NoNetwork`), the arm's limits
(:class:`ArmLimits`) and the shipped calibrations.

What it cannot do, because there is no network: the modes that read one (``learned`` and
``fused``: a parameter head; ``blend`` and ``smoothed``: the decoder; ``none``: the decoder
alone) are refused with one line. There are no training statistics,
so the range check of :attr:`Predictor.max_input_std` is off; the catalogue's limits stand in
(:class:`ArmLimits`, :attr:`Predictor.limits`): torques beyond three times the arm's motor limits (N m given as
mN m) and context joint angles outside its joint ranges (degrees given for radians) are refused.

Its standard deviation is the spread over the robots the context allows, scaled by a shipped
calibration where one was fitted for the arm and the recipe asked for: ``arm_calibrations/<arm>-<recipe>.json``
beside this module (``panda-multisine.json``, the generator's defaults, and ``panda-realistic.json``),
fitted by ``benchmarks/arm_calibration.py`` with from_arm's default settings on simulated robots that
no store of the docs or the demo holds, one calibration for windows that open their trajectory and
one for the others, with the command, commit and held-out coverage recorded in it
(:attr:`Predictor.calibration` then has its record). The file taken is the one whose scope
(:func:`calibration_scope`: arm, formulation, physics step, the recipe's ranges) is the Predictor's, so a
trained command hybrid's record of the same robots finds it too. Another arm, recipe, physics step or
input formulation has none: its std is the raw spread, not calibrated, and
:attr:`Predictor.calibration` is None (``robomorph calibrate`` fits one on a trained checkpoint).

Every registered arm has a catalogue physics backbone (:func:`robomorph.identification.backbone.parameter_layout`).
``inputs="total"`` takes the total joint torque a real arm's sensors log, gravity included (with the
recipe's ``gravity_compensation="none"``).
"""

from __future__ import annotations

import dataclasses
import json
import os

import torch

from robomorph.core.errors import RoboMorphError
from robomorph.core.names import TODAYS_RECORD

# The modes that read no network.
NETWORK_FREE_MODES = ("regression", "refined")
# The recipe benchmarks/arm_calibration.py fits on by default (the generator's defaults), and where the calibrations lie.
CALIBRATION_RECIPE = "multisine"
CALIBRATION_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "arm_calibrations")
# Recipe fields that change the data drawn but not the robots' distribution or their physics: a
# calibration fitted on 256 robots of seed 55 holds for 4 robots of seed 1.
_SAMPLING_FIELDS = ("robots", "seed", "steps", "chunk", "max_attempts_factor")


# The input check of a Predictor with no training statistics (ArmLimits): torques beyond this many times the
# arm's motor limits are refused (N m given as mN m: x1000). A command asks at most the motor's limit beyond the
# gravity compensation's share, itself within the limit (2x), and the public Kinova Gen3 logs' torques from the
# motor currents reach 1.65x its datasheet's limits (their peaks): 3x lets both by.
TORQUE_FACTOR = 3.0
# Joint angles further than this [rad] outside the catalogue's joint range are refused (degrees given for
# radians): a real arm's encoders stay within its range, and the margin lets a zero offset or an overshoot by.
JOINT_MARGIN = 0.2


class NoNetworkError(RoboMorphError, ValueError):
    """A prediction that needs a trained network, asked of a Predictor built from the arm alone."""


class LimitsError(NoNetworkError):
    """Torques or joint angles far outside a catalogue arm's limits: their units, most often."""


@dataclasses.dataclass(frozen=True)
class ArmLimits:
    """A catalogue arm's motor torque limits [N m] and joint ranges [rad], against which a Predictor with no
    training statistics (``Predictor.from_arm``) checks what it is given: torques beyond :data:`TORQUE_FACTOR` times
    the limits and joint angles :data:`JOINT_MARGIN` outside the ranges are refused, with the channel named.
    ``Predictor.limits = None`` turns the check off."""

    arm: str
    torques: tuple[float, ...]
    joints: tuple[tuple[float, float], ...]

    @classmethod
    def of(cls, arm: str) -> "ArmLimits":
        from robomorph.sim import arms  # noqa: PLC0415

        spec = arms.get(arm)
        ranges = spec.build_model(gravity_compensation=False).jnt_range[:spec.n_joint]
        return cls(spec.name, tuple(float(x) for x in spec.limits), tuple((float(lo), float(hi)) for lo, hi in ranges))

    def check(self, u_ctx: torch.Tensor, y_ctx: torch.Tensor, u_query: torch.Tensor, names: dict) -> None:
        """Refuses (:class:`LimitsError`) the first torque or context joint angle out of bounds; ``names``:
        the Predictor's record (its ``u_names`` and ``y_names`` label the channel)."""
        n = len(self.torques)
        limit = torch.tensor(self.torques, dtype=u_ctx.dtype, device=u_ctx.device)
        for what, u in (("u_ctx", u_ctx), ("u_query", u_query)):
            ratio = u.abs().reshape(-1, u.shape[-1]).amax(0)[:n] / limit
            j = int(torch.argmax(ratio))
            if float(ratio[j]) > TORQUE_FACTOR:
                label = _label(names.get("u_names"), j, "u")
                raise LimitsError(
                    f"{what} reaches {float(ratio[j] * limit[j]):.4g} N m on {label!r}, {float(ratio[j]):.3g} times "
                    f"the {self.arm}'s motor limit of {self.torques[j]:g} N m (refused above {TORQUE_FACTOR:g}x): "
                    "give the torques in N m, or set Predictor.limits = None to predict anyway")
        q = y_ctx[..., 7:7 + n].reshape(-1, n)
        lo, hi = (torch.tensor(v, dtype=q.dtype, device=q.device) for v in zip(*self.joints))
        beyond = torch.maximum(lo - q.amin(0), q.amax(0) - hi)
        j = int(torch.argmax(beyond))
        if float(beyond[j]) > JOINT_MARGIN:
            worst = float(q[:, j].amin() if float(lo[j] - q[:, j].amin()) >= float(q[:, j].amax() - hi[j])
                          else q[:, j].amax())
            label = _label(names.get("y_names"), 7 + j, "y")
            raise LimitsError(
                f"y_ctx's joint angle {label!r} reaches {worst:.4g} rad, outside the {self.arm}'s joint range "
                f"[{self.joints[j][0]:.3g}, {self.joints[j][1]:.3g}] rad by more than {JOINT_MARGIN:g}: give the "
                "angles in radians (not degrees), or set Predictor.limits = None to predict anyway")


def _label(names, j: int, kind: str) -> str:
    return str(names[j]) if names and j < len(names) else f"{kind}{j}"


@dataclasses.dataclass(frozen=True)
class _Config:
    n_u: int
    n_y: int
    patch: int = 1
    n_params: int = 0
    channel_mask: bool = False


@dataclasses.dataclass(frozen=True)
class _Normalizer:
    normalization: str = "train_stats"


class NoNetwork:
    """What a :class:`robomorph.inference.predictor.Predictor` holds in place of a trained model when there is none:
    the channel counts, no calibrations and no blend; anything that would run a network says so instead."""

    gaussian = False
    blend = None
    network_free_modes = NETWORK_FREE_MODES  # the Predictor refuses the others (check_network_free)

    def __init__(self, n_u: int, n_y: int) -> None:
        self.config = _Config(n_u, n_y)
        self.normalizer = _Normalizer()
        self.calibrations: dict = {}

    def to(self, device) -> NoNetwork:
        return self

    def eval(self) -> NoNetwork:
        return self

    def forward_dist_raw(self, *args, **kwargs) -> tuple[torch.Tensor, torch.Tensor]:
        # Never reached through a Predictor (check_network_free refuses first): a direct call says why.
        raise NoNetworkError("this model was built from the arm alone (Predictor.from_arm), with no network: "
                             f"predict with physics_mode {' or '.join(map(repr, NETWORK_FREE_MODES))}")


def arm_record(arm: str = "panda", recipe: str | None = None, inputs: str = "command", **overrides) -> dict:
    """The data record a hybrid of ``arm`` would carry, from its catalogue and a recipe.

    Args:
        arm: a name of :data:`robomorph.sim.arms.ARMS`.
        recipe: a generator recipe (a shipped name such as ``multisine`` or a YAML path; default the
            generator's defaults), whose physics step, gravity compensation and randomization ranges
            the backbone uses, as a store generated with it records them.
        inputs: ``command`` (the torque the arm is sent; it compensates its own gravity as the
            recipe says) or ``total`` (the joint torque a torque sensor measures, gravity
            included: a real arm's log, with the recipe's ``gravity_compensation: none``).
        overrides: recipe fields changed (``dt=...``, ``substeps=...``).

    Raises:
        NoNetworkError: an arm that is not registered.
    """
    from robomorph.core.inputs import check_inputs  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.identification.backbone import parameter_layout  # noqa: PLC0415
    from robomorph.sim.randomize import param_names  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    if arm not in arms.ARMS:
        raise NoNetworkError(f"unknown arm {arm!r}: a prediction with no training needs a registered arm's catalogue "
                             f"model; choose one of {', '.join(arms.names())}")
    rec = load_recipe(recipe, {"robot": arm, **overrides})
    spec = rec.arm
    attrs = {"domain": spec.name, "config": rec.to_dict(), "param_names": param_names(spec.name)}
    # As a model trained today records it (robomorph.training.module): every recorded switch on.
    physics = {**parameter_layout(attrs), "mode": "catalogue", **TODAYS_RECORD}
    inputs = check_inputs(inputs)
    # The input channels as a store names them (robomorph.data.store.Store.input_names): a trained model's
    # record has the same, so a window of a store is checked against them alike.
    u_names = spec.u_cmd_names if inputs == "command" else spec.u_names
    return {"u_names": list(u_names), "y_names": list(spec.y_names), "dt": float(rec.dt),
            "inputs": inputs,
            "stores": [], "physics": physics, "arm": spec.name}



def calibration_path(arm: str, recipe: str = CALIBRATION_RECIPE) -> str:
    """Where ``benchmarks/arm_calibration.py`` writes the std calibration of ``arm``'s untrained hybrid fitted on
    robots of ``recipe`` (a shipped name, or a YAML path: its file's stem); it may not exist."""
    name = os.path.splitext(os.path.basename(recipe))[0]
    return os.path.join(CALIBRATION_DIR, f"{arm}-{name}.json")


def calibration_files(arm: str) -> list[str]:
    """The shipped calibration files of ``arm``: one per recipe fitted on (``<arm>-<recipe>.json``), and
    ``<arm>.json`` as the first release named its one."""
    names = sorted(os.listdir(CALIBRATION_DIR)) if os.path.isdir(CALIBRATION_DIR) else []
    return [os.path.join(CALIBRATION_DIR, n) for n in names
            if n == f"{arm}.json" or (n.startswith(f"{arm}-") and n.endswith(".json"))]


def shipped_calibration_file(info: dict) -> str | None:
    """The shipped calibration file whose scope (:func:`calibration_scope`) is that of the hybrid of record
    ``info``: fitted on the same arm, formulation, physics step and recipe robots; None where there is none."""
    scope = calibration_scope(info)
    if scope is None:
        return None
    for path in calibration_files(scope["arm"]):
        with open(path) as f:
            if json.load(f).get("scope") == scope:
                return path
    return None


def calibration_scope(info: dict) -> dict | None:
    """What a shipped calibration must share with a hybrid to scale its std: the arm, the input formulation,
    the physics step and the recipe's robots (randomization ranges, gravity compensation, signal), as plain
    JSON values; not the counts or the seed (:data:`_SAMPLING_FIELDS`). ``info`` is :func:`arm_record`'s or
    a trained model's record (its ``arms``); None for a record of several arms or of no simulated recipe."""
    arms = [info["arm"]] if info.get("arm") else list(info.get("arms") or [])
    recipe = ((info.get("physics") or {}).get("recipe")) or None
    if len(arms) != 1 or recipe is None:
        return None
    recipe = {k: v for k, v in recipe.items() if k not in _SAMPLING_FIELDS}
    return json.loads(json.dumps({"arm": arms[0], "inputs": info.get("inputs", "total"), "dt": info.get("dt"),
                                  "recipe": recipe}))


def shipped_calibrations(info: dict) -> dict:
    """The shipped calibrations that apply to the hybrid of record ``info`` (:func:`arm_record`'s, or a trained
    command hybrid's, whose default mode predicts as ``Predictor.from_arm``'s), keyed as a trained model keeps its
    own (:func:`robomorph.inference.calibration.calibration_key`); {} where none applies."""
    from robomorph.inference.calibration import StdCalibration, calibration_key  # noqa: PLC0415

    path = shipped_calibration_file(info)
    if path is None:
        return {}
    with open(path) as f:
        doc = json.load(f)
    cals = [StdCalibration.from_dict(entry) for entry in doc["calibrations"].values()]
    return {calibration_key(c): c for c in cals}


def check_network_free(predictor, mode: str | None = None) -> None:
    """Refuses, in one line, a physics mode (``mode``, default the Predictor's) that reads a network, asked of a
    Predictor that has none: by :meth:`~robomorph.inference.predictor.Predictor.configure` before it changes
    anything, and by :func:`robomorph.inference.predictor_checks.check_settings` before anything runs."""
    free = getattr(predictor.model, "network_free_modes", None)
    mode = predictor.settings.mode if mode is None else mode
    if free is not None and mode not in free:
        raise NoNetworkError(f"physics mode {mode!r} reads a trained network, and this Predictor "
                             f"was built from the arm alone (Predictor.from_arm): use {' or '.join(map(repr, free))}, "
                             "or load a trained checkpoint (Predictor.from_checkpoint)")
