"""What ``ingest`` does to real logs beyond cutting windows: resampling and the Panda layout.

* ``--resample HZ``: torque-controlled arms log at 1 kHz, models are trained at tens of Hz.
  Taking every n-th sample folds everything above the new Nyquist frequency (motor noise,
  a 400 Hz vibration) onto the slow signal; :func:`resample` filters first
  (``scipy.signal.resample_poly``: a Kaiser-windowed low-pass FIR at the new Nyquist
  frequency, applied by a polyphase filter), so the store holds what a sensor at the new
  rate with an anti-aliasing filter would have recorded. The store keeps the log's rate in
  ``attrs['original_dt']``.
* ``--layout ARM`` (``panda``, ``kinova3``, ``ur5e``, ... any arm of :mod:`robomorph.sim.arms`):
  a log of that arm's joint torques and joint angles is stored with the simulator's channel
  names and ``y`` (EE x y z, EE quaternion X Y Z W, q0..q{n-1}), the pose computed from the
  joint angles with the catalogue model's kinematics (:func:`robomorph.sim.kinematics.ee_pose`),
  so a model trained in simulation reads it and the catalogue physics can be simulated beside
  it; the store records the arm (``attrs['arm']``).
* ``--layout joints``: a log of any arm's joint torques and joint angles, in joint order, is
  stored with the channels named by role (``tau0..``, ``cmd0..``, ``q0..``), as the
  simulator names every arm's, so a model of several arms maps them onto its own channels
  (its end-effector pose channels stay absent: an unknown arm's kinematics is not assumed).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from robomorph.core.errors import RoboMorphError

LAYOUTS = ("joints", "ARM")  # ARM: any name of robomorph.sim.arms.names()
# Largest relative difference between the asked rate ratio and the integer ratio used.
_RATIO_TOL = 1e-3


class RealLogError(RoboMorphError, ValueError):
    """A resampling rate or layout that the logs cannot be given."""


def check_rate(hz: float) -> None:
    """Refuses a ``--resample`` rate that is not a positive, finite number of Hz."""
    if not (math.isfinite(hz) and hz > 0):
        raise RealLogError(f"--resample must be a positive, finite rate in Hz, got {hz}")


def rate_ratio(dt: float, hz: float) -> tuple[int, int]:
    """``(up, down)``: the small integers whose ratio turns samples ``dt`` apart into ``hz``."""
    check_rate(hz)
    exact = dt * hz  # new rate / old rate
    ratio = Fraction(exact).limit_denominator(1000)
    # Both ends bounded: an upsampling factor of 10^6 would allocate tens of GiB per log.
    if ratio == 0 or ratio.numerator > 1000 or abs(float(ratio) - exact) > _RATIO_TOL * exact:
        raise RealLogError(f"cannot resample from {1 / dt:.6g} Hz to {hz:.6g} Hz by a ratio of integers up to 1000; "
                           "choose a rate that divides the log's (e.g. 1000 Hz -> 100, 125, 200 or 250 Hz)")
    return ratio.numerator, ratio.denominator


def resample(x: np.ndarray, dt: float, hz: float) -> np.ndarray:
    """(L, C) samples ``dt`` apart -> (L', C) at ``hz``, low-pass filtered against aliasing.

    The ends are padded by extending the signal linearly (``padtype="line"``), not with
    zeros, so a log that does not start and end at 0 gets no transient at its edges.
    """
    from scipy.signal import resample_poly  # noqa: PLC0415  (scipy only when resampling)

    up, down = rate_ratio(dt, hz)
    if up == down:
        return np.asarray(x, dtype=np.float32)
    out = resample_poly(np.asarray(x, dtype=np.float64), up, down, axis=0, padtype="line")
    return out.astype(np.float32)


def layout_arm(layout: str | None):
    """The registered arm a layout names, or None (no layout, or ``joints``).

    Raises:
        RealLogError: the layout is neither ``joints`` nor a registered arm.
    """
    if layout in (None, "joints"):
        return None
    from robomorph.sim import arms  # noqa: PLC0415  (MuJoCo only for an arm's layout)

    if layout not in arms.ARMS:
        raise RealLogError(f"unknown --layout {layout!r}; choose joints or one of the arms {', '.join(arms.names())}")
    return arms.ARMS[layout]


def check_layout(layout: str | None, u_cols: list[str], y_cols: list[str], u_cmd_cols: list[str] | None) -> None:
    """Refuses a layout the columns do not fit (an arm: one torque and one joint angle per joint;
    joints: one torque per joint angle)."""
    if layout == "joints":
        for flag, cols in (("--u-cols", u_cols), ("--u-cmd-cols", u_cmd_cols)):
            if cols is not None and len(cols) != len(y_cols):
                raise RealLogError(f"--layout joints needs one {flag} column per joint angle in --y-cols (joint "
                                   f"order), got {len(cols)} and {len(y_cols)}")
        return
    arm = layout_arm(layout)
    if arm is None:
        return
    for flag, cols in (("--u-cols", u_cols), ("--y-cols", y_cols), ("--u-cmd-cols", u_cmd_cols)):
        if cols is not None and len(cols) != arm.n_joint:
            raise RealLogError(f"--layout {arm.name} needs {arm.n_joint} {flag} (joints 1..{arm.n_joint} in order: "
                               f"torques for --u-cols/--u-cmd-cols, joint angles in rad for --y-cols), got {len(cols)}")


def apply_layout(layout: str | None, y: np.ndarray) -> np.ndarray:
    """``y`` in the layout's channels: for an arm, (L, n) joint angles -> (L, 7 + n) pose + angles."""
    arm = layout_arm(layout)
    if arm is None:
        return y
    from robomorph.sim.kinematics import ee_pose  # noqa: PLC0415  (MuJoCo only for this layout)

    model = _catalogue(arm.name)
    _check_angles(arm, model, y)
    return np.concatenate([ee_pose(y, model), y], axis=1).astype(np.float32)


# How far past a joint's limit a logged angle may lie (encoder offsets, a limit reached hard).
_LIMIT_SLACK = 0.2  # rad


def _check_angles(arm, model, y: np.ndarray) -> None:
    """Refuses joint angles beyond the arm's limits: angles in degrees, most often, whose EE
    pose would still look plausible. Joints without limits (continuous) are not checked."""
    import mujoco  # noqa: PLC0415

    for k, name in enumerate(arm.joint_names[:y.shape[1]]):
        j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if j < 0 or not model.jnt_limited[j]:
            continue
        lo, hi = (float(v) for v in model.jnt_range[j])
        worst = float(np.nanmax(np.abs(y[:, k] - np.clip(y[:, k], lo, hi)))) if len(y) else 0.0
        if worst > _LIMIT_SLACK:
            raise RealLogError(f"joint {k + 1} ({name}) of the {arm.name} layout reaches {worst:.3g} rad past its limits "
                               f"[{lo:.3g}, {hi:.3g}] rad: are the angles in degrees? convert them to radians (or "
                               "check the order of --y-cols)")


def _catalogue(name: str):
    from robomorph.sim import arms  # noqa: PLC0415

    return arms.ARMS[name].build_model(gravity_compensation=False)


def layout_names(layout: str | None, u_cols: list[str], y_cols: list[str], u_cmd_cols: list[str] | None,
                 y_units: list[str] | None) -> tuple[list[str], list[str], list[str] | None, list[str] | None]:
    """``(u names, y names, u_cmd names, y units)`` of the store: the columns' own names, or the layout's."""
    if layout is None:
        return list(u_cols), list(y_cols), None if u_cmd_cols is None else list(u_cmd_cols), y_units
    if layout == "joints":
        n = len(y_cols)
        return ([f"tau{k}" for k in range(n)], [f"q{k}" for k in range(n)],
                None if u_cmd_cols is None else [f"cmd{k}" for k in range(n)], y_units)
    arm = layout_arm(layout)
    units = ["m"] * 3 + [""] * 4 + list(y_units or ["rad"] * arm.n_joint)
    return (list(arm.u_names), list(arm.y_names), None if u_cmd_cols is None else list(arm.u_cmd_names), units)
