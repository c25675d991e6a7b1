"""What a real arm has beyond the robot's parameter vector, identified beside it.

``offsets``: a constant torque per joint, linear in itself, so one more column per joint in the
regression's solve (:mod:`robomorph.identification.regressor`). It stands for a torque sensor's
offset, for the part of a friction that differs by direction (Coulomb levels ``Fc+`` and ``Fc-``
act as their mean plus a constant ``(Fc- - Fc+) / 2`` while the joint moves one way), and for the
mean over the context of a gravity the controller does not compensate (an unconfigured payload).
A backbone simulates it by taking it off the torques it is given (:func:`corrected`): the motion
under torque ``u`` of a robot whose joints also feel ``-b`` is the robot's under ``u - b``.

``payload`` is not a column either: a mass fixed to the flange is the flange body's mass and centre of
mass changed (:func:`payload_space`), which the regression fits as it fits the links' (their gravity
is linear in the masses and in the centres of mass) and the backbone simulates; its inertia about its
own centre is left out (a point mass's, second order in the centre's offset).

``coulomb`` is not a column: MuJoCo's friction loss *is* a Coulomb friction (a soft constraint),
so a real joint's larger Coulomb and viscous friction are the friction loss and the damping with
bounds beyond the randomization box (:func:`friction_space`), which the backbone then simulates as
it simulates any robot.
"""

from __future__ import annotations

import dataclasses

import numpy as np

EXTRAS = ("offsets",)
# The offsets' bounds, as a fraction of each joint's torque limit (Panda: 4.35 N m on the large joints,
# 0.6 on the wrist): the realism recipes' sensor offsets reach 1 % and their friction asymmetry 0.2 x 0.78 N m;
# an unconfigured 1 kg payload's mean gravity over a context can reach several N m on the shoulder.
OFFSET_FRACTION = 0.05
# ``coulomb``: the friction loss's upper bound as this multiple of its catalogue value (Panda: 0.25 to 1.2 N m)
# and the damping's as this multiple of the box's upper bound. The realistic recipe's joints have a Coulomb level
# of the box's friction loss plus 0.15-0.65 N m (+-20 % by direction): up to 4.7 times the catalogue's on the
# Panda's second joint; and 0-0.2 N m s/rad of viscous friction beside the 5-10 of damping.
COULOMB_SCALE = 5.0
DAMPING_SCALE = 1.5
# ``payload``: the flange body's mass may grow by this much [kg] and its centre of mass move this far [m] per axis
# (the realism recipes' payloads: up to 1 kg, its centre of mass within 5 cm of the flange per axis).
PAYLOAD_MASS = 1.5
PAYLOAD_COM = 0.06


def check(extras) -> tuple[str, ...]:
    """The extra terms in :data:`EXTRAS` order; an unknown one is refused with the names there are."""
    extras = tuple(extras)
    bad = [e for e in extras if e not in EXTRAS]
    if bad:
        raise ValueError(f"unknown extra terms {bad}; the regression identifies {', '.join(EXTRAS)}")
    return tuple(e for e in EXTRAS if e in extras)


def half_ranges(extras: tuple[str, ...], limits: np.ndarray) -> np.ndarray:
    """(e,) half the bounds' width of each extra column [N m]: one unit coordinate."""
    parts = [OFFSET_FRACTION * np.asarray(limits, dtype=np.float64) for e in extras if e == "offsets"]
    return np.concatenate(parts) if parts else np.zeros(0)


def columns(extras: tuple[str, ...], v: np.ndarray, half: np.ndarray) -> np.ndarray:
    """(T * nj, e) the extra terms' torque per unit coordinate at ``T`` states (joint velocities ``v`` (T, nj)),
    rows in the regression's order (state-major, then joint)."""
    t, nj = v.shape
    if not extras:
        return np.zeros((t * nj, 0))
    # offsets: joint j's row of every state gets its own column, one unit coordinate of torque
    return np.tile(np.diag(half[:nj]), (t, 1))


def zeros(nj: int) -> dict[str, np.ndarray]:
    return {e: np.zeros(nj) for e in EXTRAS}


def values(extras: tuple[str, ...], x: np.ndarray | None, nj: int) -> dict[str, np.ndarray]:
    """{term: (nj,) value [N m]} of a solve's extra entries ``x`` (physical units; zeros for terms off)."""
    out = zeros(nj)
    for i, e in enumerate(extras):
        out[e] = np.asarray(x[i * nj:(i + 1) * nj], dtype=np.float64).copy()
    return out


def corrected(torque: np.ndarray, offsets: np.ndarray | None) -> np.ndarray:
    """``torque`` (B, T, nj) less each window's identified ``offsets`` (B, nj): what the robot's own dynamics
    receive (None: the torque as given)."""
    torque = np.asarray(torque, dtype=np.float64)
    return torque if offsets is None else torque - np.asarray(offsets, dtype=np.float64)[:, None, :]


def friction_space(space, randomizer, recipe_cfg):
    """``space`` (a :class:`robomorph.identification.identify.ParameterSpace`) with the friction losses' upper
    bounds raised to :data:`COULOMB_SCALE` times the catalogue value and the damping's to :data:`DAMPING_SCALE`
    times the box's, lower bounds at zero friction loss and the box's damping: a real joint's Coulomb and viscous
    friction, which exceed the randomization box, in MuJoCo's own friction loss and damping."""
    low, high = space.low.copy(), space.high.copy()
    gain = randomizer.gain
    for c, name in enumerate(space.names):
        kind, _, joint = name.rpartition("_q")
        if not joint.isdigit():
            continue
        j = int(joint)
        if kind == "frictionloss":
            low[c], high[c] = 0.0, COULOMB_SCALE * randomizer.friction0[j]
        elif kind == "damping":
            high[c] = DAMPING_SCALE * recipe_cfg.damping[1] * gain[j]
    return dataclasses.replace(space, low=low, high=high)


def flange_entries(space, randomizer, model) -> tuple[list[int], list[int]]:
    """(mass, centre-of-mass) positions in ``space`` of the randomized body that carries the ``ee`` site: the site's
    own, or the nearest one above it (some arms hang the site on a massless body fixed to the flange); none where
    no randomized body carries it."""
    body = int(model.site_bodyid[randomizer.index.ee_site])
    while body > 0 and body not in randomizer.index.body_ids:
        body = int(model.body_parentid[body])
    if body not in randomizer.index.body_ids:
        return [], []
    k = int(np.flatnonzero(randomizer.index.body_ids == body)[0])
    name = randomizer.names[k][len("mass_"):]  # the vector names a body's entries mass_<body>, com_<body>_<axis>
    mass = [c for c, n in enumerate(space.names) if n == f"mass_{name}"]
    com = [c for c, n in enumerate(space.names) if n.startswith(f"com_{name}_")]
    return mass, com


def payload_space(space, randomizer, model):
    """``space`` with the flange body's mass bounds raised by :data:`PAYLOAD_MASS` and its centre of mass's widened
    by :data:`PAYLOAD_COM` each way: an unknown payload, in the robot's own entries."""
    low, high = space.low.copy(), space.high.copy()
    mass, com = flange_entries(space, randomizer, model)
    high[mass] += PAYLOAD_MASS
    low[com] -= PAYLOAD_COM
    high[com] += PAYLOAD_COM
    return dataclasses.replace(space, low=low, high=high)
