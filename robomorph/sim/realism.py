"""Realism terms of the simulated robot: what a real arm's log has that a clean simulation lacks.

Every term is a field of :class:`RealismConfig` (the recipe's ``realism`` section), off by
default so that clean recipes make the very same arrays. Per trajectory, :func:`draw` takes
every realism quantity from a stream of its own (``SeedSequence(seed, spawn_key=(index, 1))``),
so switching a term on never changes the robot, signal or path an attempt draws; the drawn
values are returned as one named vector (:func:`names`) that the store keeps in its
``realism`` array.

The terms, their default ranges in ``datamodules/realistic.yaml`` and the sources of those
ranges are in ``docs/guide/realism.md``:

* encoder noise and quantization on the logged joint angles (the EE pose recomputed from them);
* the joint torque sensor: noise, a per-joint offset and a per-joint scale error on ``u``;
* latency between the command and its effect, and logging at the physics rate (about 1 kHz)
  brought to the model's rate by ingest's own anti-aliasing filter (in :mod:`robomorph.data.generation`);
* a payload at the flange (mass and centre of mass) that the controller's gravity compensation
  may not know;
* Coulomb + viscous + Stribeck friction, asymmetric per direction, as a passive joint force;
* robots drawn outside the identification box (``widen``, applied in :mod:`robomorph.sim.randomize`);
* feedback-controlled excitation: a joint PD tracks a multi-sine reference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from robomorph.core.config import check_number, check_range

# Upper bounds of the realism terms: far beyond any real arm (the sources in docs/guide/realism.md
# are a few mrad of encoder noise, a few percent of torque noise, a few kg of payload, a few
# physics steps of latency), and short of what would overflow a draw, allocate gigabytes or
# make the physics meaningless. Every number of the section is also checked finite.
MAX_ENCODER = 1.0  # rad, noise std and quantization step
MAX_LATENCY = 1000  # physics steps (about 1 s at 1 kHz): the delay buffer holds this many torques
MAX_PAYLOAD = 100.0  # kg
MAX_COM = 1.0  # m from the flange
MAX_FRICTION = 1000.0  # N m (Coulomb) and N m s / rad (viscous), before the per-joint gain
MAX_STRIBECK_RATIO = 100.0
MAX_SPEED = 100.0  # rad/s, the Stribeck and smoothing speeds
MAX_GAIN_SCALE = 100.0
MAX_AMPLITUDE = 3.2  # rad (about pi): a reference beyond it turns a joint through a whole turn
MAX_RAMP = 3600.0  # s
MAX_WIDEN = 100.0

# The Panda's joint impedance gains of libfranka's ``joint_impedance_control`` example
# [N m / rad] and [N m s / rad]; other arms scale them by Arm.joint_gain (joints matched by role).
PANDA_KP = (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)
PANDA_KD = (50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0)
# The multi-sine's harmonics, as the paper's torque multi-sine has them (robomorph.sim.signals).
_HARMONICS = np.array([1.0, 1.5, 2.0, 3.0])


def _off(rng: tuple[float, float]) -> bool:
    return rng[0] == rng[1] == 0


@dataclass(frozen=True)
class EncoderConfig:
    """Joint angle measurement.

    Attributes:
        noise: Gaussian noise std [rad], drawn U(lo, hi) per trajectory.
        resolution: quantization step [rad], drawn U(lo, hi) per trajectory (0: none).
        pose_from_joints: the EE pose in ``y`` is the forward kinematics of the logged
            (noisy) joints, as a real arm computes its pose from its encoders; otherwise the
            simulator's exact pose is kept.
    """

    noise: tuple[float, float] = (0.0, 0.0)
    resolution: tuple[float, float] = (0.0, 0.0)
    pose_from_joints: bool = True

    def __post_init__(self):
        check_range("realism.encoder.noise", self.noise, 0.0, MAX_ENCODER)
        check_range("realism.encoder.resolution", self.resolution, 0.0, MAX_ENCODER)

    @property
    def active(self) -> bool:
        return not (_off(self.noise) and _off(self.resolution))


@dataclass(frozen=True)
class TorqueSensorConfig:
    """Joint torque measurement, as fractions of each joint's torque limit.

    The logged torque is ``scale * tau + offset + noise`` per joint; the logged command
    (``u_cmd``) is what the controller sent and stays exact, as a real arm logs both
    (libfranka's ``tau_J`` and ``tau_J_d``).

    Attributes:
        noise: noise std as a fraction of the limit, drawn U(lo, hi) per trajectory.
        offset: per-joint offset U(-o, o) times the limit.
        scale: per-joint gain error: scale U(1 - s, 1 + s).
    """

    noise: tuple[float, float] = (0.0, 0.0)
    offset: float = 0.0
    scale: float = 0.0

    def __post_init__(self):
        check_range("realism.torque.noise", self.noise, 0.0, 1.0)
        check_number("realism.torque.offset", self.offset, 0.0, 1.0, high_open=True)
        check_number("realism.torque.scale", self.scale, 0.0, 1.0, high_open=True)

    @property
    def active(self) -> bool:
        return not _off(self.noise) or self.offset > 0 or self.scale > 0


@dataclass(frozen=True)
class TimingConfig:
    """When a command acts and how the log is sampled.

    Attributes:
        latency: physics steps between a command and its effect, an integer drawn
            uniformly in [lo, hi] per trajectory (the whole torque, compensation included).
        log_physics_rate: record every physics step (``dt / substeps``, e.g. 960 Hz) and bring
            the log to ``dt`` through ingest's anti-aliasing resampler, as a real 1 kHz log is
            (``robomorph ingest --resample``); the EE pose is then the kinematics of the
            resampled joints, as ``ingest --layout`` computes it.
    """

    latency: tuple[int, int] = (0, 0)
    log_physics_rate: bool = False

    def __post_init__(self):
        check_range("realism.timing.latency", self.latency, 0, MAX_LATENCY)
        if any(int(x) != x for x in self.latency):
            raise ValueError(f"realism.timing.latency counts physics steps: give integers, got {self.latency}")


@dataclass(frozen=True)
class PayloadConfig:
    """A point mass fixed to the flange (the body that carries the ``ee`` site).

    Attributes:
        mass: payload mass [kg], drawn U(lo, hi) per trajectory.
        com: each coordinate of its centre of mass in the flange frame, U(-c, c) [m].
        configured: probability that the payload is configured, i.e. known to the
            controller's gravity compensation (``gravity_compensation: nominal_model``).
    """

    mass: tuple[float, float] = (0.0, 0.0)
    com: float = 0.0
    configured: float = 1.0

    def __post_init__(self):
        check_range("realism.payload.mass", self.mass, 0.0, MAX_PAYLOAD)
        check_number("realism.payload.com", self.com, 0.0, MAX_COM)
        check_number("realism.payload.configured", self.configured, 0.0, 1.0)

    @property
    def active(self) -> bool:
        return self.mass[1] > 0


@dataclass(frozen=True)
class FrictionConfig:
    """Joint friction beyond MuJoCo's frictionloss and damping (a passive force each physics step).

    Per joint and direction d (+ or -), for joint speed v:
    ``tau = -[(Fc_d + (Fs_d - Fc_d) exp(-(v / vs)^2)) tanh(v / v_smooth) + Fv_d v]``.
    Coulomb and viscous values are the Panda's and scale per joint with Arm.joint_gain.

    Attributes:
        coulomb: Coulomb level Fc [N m], drawn U(lo, hi) per joint.
        viscous: viscous coefficient Fv [N m s / rad], U(lo, hi) per joint.
        stribeck_ratio: static over Coulomb level Fs / Fc, U(lo, hi) per joint.
        stribeck_velocity: Stribeck speed vs [rad/s], U(lo, hi) per joint.
        asymmetry: each direction's Fc and Fv scaled by 1 + U(-a, a), drawn per direction.
        smoothing_velocity: speed [rad/s] of the tanh that replaces sign(v): an explicit
            force of slope Fs / v_smooth at rest must stay stable at the physics step.
    """

    coulomb: tuple[float, float] = (0.0, 0.0)
    viscous: tuple[float, float] = (0.0, 0.0)
    stribeck_ratio: tuple[float, float] = (1.0, 1.0)
    stribeck_velocity: tuple[float, float] = (0.1, 0.1)
    asymmetry: float = 0.0
    smoothing_velocity: float = 0.1

    def __post_init__(self):
        for name in ("coulomb", "viscous"):
            check_range(f"realism.friction.{name}", getattr(self, name), 0.0, MAX_FRICTION)
        check_range("realism.friction.stribeck_ratio", self.stribeck_ratio, 1.0, MAX_STRIBECK_RATIO)
        check_range("realism.friction.stribeck_velocity", self.stribeck_velocity, 0.0, MAX_SPEED)
        if not self.stribeck_velocity[0] > 0:
            raise ValueError("realism.friction.stribeck_velocity must be > 0")
        # An infinite smoothing speed would make tanh(v / v_smooth) zero: Coulomb friction off
        # while the store records its drawn levels.
        check_number("realism.friction.smoothing_velocity", self.smoothing_velocity, 0.0, MAX_SPEED, low_open=True)
        check_number("realism.friction.asymmetry", self.asymmetry, 0.0, 1.0, high_open=True)

    @property
    def active(self) -> bool:
        return not (_off(self.coulomb) and _off(self.viscous))


@dataclass(frozen=True)
class FeedbackConfig:
    """Feedback-controlled excitation of the ``multisine`` task: a joint PD, updated every
    physics step, tracks a joint-space multi-sine around the initial pose; the logged
    torque is what it applied (plus the gravity compensation), ``u_cmd`` its PD part.

    Attributes:
        enabled: track a reference instead of applying the open-loop torque multi-sine.
        kp, kd: the Panda's joint gains (7 values; other arms take them by joint role,
            scaled by Arm.joint_gain).
        gain_scale: both gains scaled by U(lo, hi) per trajectory.
        amplitude: per joint, the reference's amplitude budget [rad], U(lo, hi); its four
            harmonics get U(-1, 1) quarters of it.
        ramp: seconds over which the reference fades in (a smoothstep), so the robot starts
            at rest on its reference.
    """

    enabled: bool = False
    kp: tuple[float, ...] = PANDA_KP
    kd: tuple[float, ...] = PANDA_KD
    gain_scale: tuple[float, float] = (0.5, 1.0)
    amplitude: tuple[float, float] = (0.1, 0.4)
    ramp: float = 1.0

    def __post_init__(self):
        if (len(self.kp) != 7 or len(self.kd) != 7 or not all(np.isfinite([*self.kp, *self.kd]))
                or min(self.kp) <= 0 or min(self.kd) < 0):
            raise ValueError("realism.feedback.kp and kd need 7 finite values each (kp > 0, kd >= 0)")
        check_range("realism.feedback.gain_scale", self.gain_scale, 0.0, MAX_GAIN_SCALE)
        check_range("realism.feedback.amplitude", self.amplitude, 0.0, MAX_AMPLITUDE)
        if not self.gain_scale[0] > 0:
            raise ValueError("realism.feedback.gain_scale must be > 0")
        check_number("realism.feedback.ramp", self.ramp, 0.0, MAX_RAMP)


@dataclass(frozen=True)
class RealismConfig:
    """The recipe's realism terms (all off by default: a clean recipe's arrays do not change).

    Attributes:
        encoder, torque, timing, payload, friction, feedback: see each section.
        widen: the randomization ranges are widened about their middles by this factor for
            the draw (1: the ranges as written). The recipe's ``randomization`` stays the box
            the identification is bounded to, so robots fall outside it.
    """

    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    torque: TorqueSensorConfig = field(default_factory=TorqueSensorConfig)
    timing: TimingConfig = field(default_factory=TimingConfig)
    payload: PayloadConfig = field(default_factory=PayloadConfig)
    friction: FrictionConfig = field(default_factory=FrictionConfig)
    feedback: FeedbackConfig = field(default_factory=FeedbackConfig)
    widen: float = 1.0

    def __post_init__(self):
        check_number("realism.widen (1 keeps the ranges)", self.widen, 1.0, MAX_WIDEN)
        if self.timing.log_physics_rate and not self.encoder.pose_from_joints:
            raise ValueError("realism.timing.log_physics_rate computes the EE pose from the resampled joints: "
                             "set realism.encoder.pose_from_joints: true")

    @property
    def enabled(self) -> bool:
        """Whether any term differs from a clean recipe."""
        return self != RealismConfig()

    @property
    def steps_in_python(self) -> bool:
        """Whether the physics needs Python at every physics step (the closed-loop engine)."""
        t = self.timing
        return (self.friction.active or self.payload.active or self.feedback.enabled
                or t.latency[1] > 0 or t.log_physics_rate)


def joint_roles(n: int) -> np.ndarray:
    """(n,) the Panda joint of the same role: the first n - 3 from the base, the last 3 the wrist."""
    return np.array([i if i < n - 3 else i + 7 - n for i in range(n)])


# One name per drawn quantity; "{j}" expands per joint.
_FIELDS = (("encoder_noise", False), ("encoder_resolution", False), ("torque_noise_q{j}", True),
           ("torque_offset_q{j}", True), ("torque_scale_q{j}", True), ("latency", False),
           ("payload_mass", False), ("payload_com_x", False), ("payload_com_y", False),
           ("payload_com_z", False), ("payload_configured", False),
           ("coulomb_pos_q{j}", True), ("coulomb_neg_q{j}", True), ("viscous_pos_q{j}", True),
           ("viscous_neg_q{j}", True), ("stribeck_ratio_q{j}", True), ("stribeck_velocity_q{j}", True),
           ("feedback_kp_q{j}", True), ("feedback_kd_q{j}", True), ("feedback_amplitude_q{j}", True))


def names(n_joint: int) -> list[str]:
    """Names of the realism vector of an arm with ``n_joint`` joints (units: rad, N m, s, kg, m)."""
    return [name.format(j=j) for name, per in _FIELDS for j in (range(n_joint) if per else [None])]


@dataclass
class Realization:
    """The realism quantities one trajectory drew (physical units; zeros where a term is off)."""

    encoder_noise: float
    encoder_resolution: float
    torque_noise: np.ndarray  # (n,) std [N m]
    torque_offset: np.ndarray  # (n,) [N m]
    torque_scale: np.ndarray  # (n,)
    latency: int  # physics steps
    payload_mass: float
    payload_com: np.ndarray  # (3,) in the flange frame [m]
    payload_configured: bool
    coulomb: np.ndarray  # (2, n): + and - direction [N m]
    viscous: np.ndarray  # (2, n) [N m s / rad]
    stribeck_ratio: np.ndarray  # (n,)
    stribeck_velocity: np.ndarray  # (n,) [rad/s]
    kp: np.ndarray  # (n,) feedback gains (zeros without feedback)
    kd: np.ndarray
    amplitude: np.ndarray  # (n,) [rad]
    reference: np.ndarray | None = None  # (4, n, 3) harmonics: amplitude, angular frequency, phase

    def vector(self) -> np.ndarray:
        """The values in :func:`names` order (float64)."""
        parts = [self.encoder_noise, self.encoder_resolution, self.torque_noise, self.torque_offset,
                 self.torque_scale, self.latency, self.payload_mass, *self.payload_com,
                 float(self.payload_configured), self.coulomb[0], self.coulomb[1], self.viscous[0],
                 self.viscous[1], self.stribeck_ratio, self.stribeck_velocity, self.kp, self.kd, self.amplitude]
        return np.concatenate([np.atleast_1d(np.asarray(p, dtype=np.float64)) for p in parts])


def realism_rng(seed: int, index: int) -> np.random.Generator:
    """The realism stream of attempt ``index``: a sibling of its main stream, so the robot,
    signal and path an attempt draws do not depend on which realism terms are on."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index, 1)))


def draw(cfg: RealismConfig, rng: np.random.Generator, limits: np.ndarray, gain: np.ndarray,
         fm: float, feedback: bool) -> Realization:
    """Draws one trajectory's realism quantities (always the same number of draws, in one order).

    Args:
        cfg: the recipe's realism terms.
        rng: the attempt's realism stream (:func:`realism_rng`).
        limits: (n,) the arm's torque limits [N m].
        gain: (n,) Arm.joint_gain (scales friction and feedback gains).
        fm: the trajectory's main frequency [Hz] (the feedback reference's).
        feedback: whether this trajectory is feedback-controlled (its reference is drawn).
    """
    n, e, ts, p, f, fb = len(limits), cfg.encoder, cfg.torque, cfg.payload, cfg.friction, cfg.feedback
    out = Realization(
        encoder_noise=float(rng.uniform(*e.noise)), encoder_resolution=float(rng.uniform(*e.resolution)),
        torque_noise=rng.uniform(*ts.noise) * limits,
        torque_offset=rng.uniform(-ts.offset, ts.offset, n) * limits,
        torque_scale=rng.uniform(1 - ts.scale, 1 + ts.scale, n),
        latency=int(rng.integers(int(cfg.timing.latency[0]), int(cfg.timing.latency[1]) + 1)),
        payload_mass=float(rng.uniform(*p.mass)), payload_com=rng.uniform(-p.com, p.com, 3),
        payload_configured=bool(rng.uniform() < p.configured),
        coulomb=rng.uniform(*f.coulomb, n) * gain * (1 + rng.uniform(-f.asymmetry, f.asymmetry, (2, n))),
        viscous=rng.uniform(*f.viscous, n) * gain * (1 + rng.uniform(-f.asymmetry, f.asymmetry, (2, n))),
        stribeck_ratio=rng.uniform(*f.stribeck_ratio, n), stribeck_velocity=rng.uniform(*f.stribeck_velocity, n),
        kp=np.zeros(n), kd=np.zeros(n), amplitude=np.zeros(n))
    if not p.active:
        out.payload_com[:] = 0.0
    if feedback:
        role, scale = joint_roles(n), rng.uniform(*fb.gain_scale)
        out.kp = np.asarray(fb.kp)[role] * gain * scale
        out.kd = np.asarray(fb.kd)[role] * gain * scale
        out.amplitude = rng.uniform(*fb.amplitude, n)
        f0 = rng.uniform(fm / 1.5, 1.5 * fm, n)
        amp = rng.uniform(-1, 1, (4, n)) * out.amplitude / 4
        omega = 2 * np.pi * _HARMONICS[:, None] * f0
        out.reference = np.stack([amp, omega, rng.uniform(-np.pi, np.pi, (4, n))], axis=-1)
    return out


def reference(real: Realization, q0: np.ndarray, t: np.ndarray, ramp: float) -> tuple[np.ndarray, np.ndarray]:
    """The feedback reference at times ``t`` (K,): positions and velocities (K, n).

    A multi-sine that starts at 0 (each sine less its value at t = 0), faded in by a smoothstep
    over ``ramp`` seconds so that the reference starts at rest on the initial pose.
    """
    amp, omega, phase = (real.reference[..., i][:, None] for i in range(3))  # (4, 1, n)
    arg = omega * t[None, :, None] + phase  # (4, K, n)
    s = (amp * (np.sin(arg) - np.sin(phase))).sum(0)
    ds = (amp * omega * np.cos(arg)).sum(0)
    if ramp > 0:
        x = np.clip(t / ramp, 0.0, 1.0)[:, None]
        r, dr = x * x * (3 - 2 * x), np.where(x < 1, 6 * x * (1 - x) / ramp, 0.0)
        s, ds = r * s, dr * s + r * ds
    return q0 + s, ds


def friction_torque(real: Realization, qvel: np.ndarray, v_smooth: float) -> np.ndarray:
    """The passive friction torque at joint speeds ``qvel`` (opposes the motion)."""
    return Friction(real, v_smooth)(qvel)


class Friction:
    """:func:`friction_torque` of one trajectory, its coefficients laid out once for the physics
    steps (a call costs a few microseconds)."""

    def __init__(self, real: Realization, v_smooth: float):
        self.fc_pos, self.fc_neg = real.coulomb
        self.fv_pos, self.fv_neg = real.viscous
        self.hump = real.stribeck_ratio - 1
        self.inv_vs, self.inv_smooth = 1.0 / real.stribeck_velocity, 1.0 / v_smooth

    def __call__(self, qvel: np.ndarray) -> np.ndarray:
        neg = qvel < 0  # each direction has its own Coulomb and viscous coefficients
        fc, fv = np.where(neg, self.fc_neg, self.fc_pos), np.where(neg, self.fv_neg, self.fv_pos)
        x = qvel * self.inv_vs
        level = fc * (1 + self.hump * np.exp(-x * x))
        return -(level * np.tanh(qvel * self.inv_smooth) + fv * qvel)


def sense(tau: np.ndarray, q: np.ndarray, real: Realization, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The logged torque and joint angles: the sensors' errors on the true (T, n) values.

    Encoder: noise, then the count (quantization). Torque sensor: scale, offset, noise.
    """
    q_log = q + rng.normal(0.0, 1.0, q.shape) * real.encoder_noise
    if real.encoder_resolution > 0:
        q_log = np.round(q_log / real.encoder_resolution) * real.encoder_resolution
    tau_log = tau * real.torque_scale + real.torque_offset + rng.normal(0.0, 1.0, tau.shape) * real.torque_noise
    return tau_log, q_log

