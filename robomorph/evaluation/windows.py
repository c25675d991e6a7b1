"""The windows an evaluation scores: ``context_len + horizon`` steps of each trajectory.

By default every window opens the trajectory (the paper's protocol: the robot starts at
rest). ``--offset random`` starts each trajectory's window at its own random step, drawn
from a seeded stream, so the model is scored mid-motion as a controller meets it;
``--offset N`` starts every window at step ``N``. Windows always lie inside the data.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from robomorph.core.channels import columns
from robomorph.core.errors import RoboMorphError


class WindowError(RoboMorphError, ValueError):
    """An evaluation window that the store cannot supply; the message says what to change."""


@dataclass
class Window:
    """What one evaluation scores: ``n`` trajectory windows split at ``context_len``."""

    u: np.ndarray  # (N, context_len + horizon, n_u)
    y: np.ndarray  # (N, context_len + horizon, n_y)
    context_len: int
    horizon: int
    u_names: list[str]
    y_names: list[str]
    dt: float
    attrs: dict
    params: np.ndarray  # (N, P) the stored physical parameters (P may be 0)
    starts: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (N,) first step of each window
    y_first: np.ndarray | None = None  # (N, n_y) each trajectory's first output (where the robot started)
    inputs: str = "total"  # which array u is: the total torque (u) or the command (u_cmd)

    def split(self, context_len: int | None = None, horizon: int | None = None):
        """``u_ctx, y_ctx, u_query, y_query`` with the query always starting at ``self.context_len``."""
        c, h, c0 = context_len or self.context_len, horizon or self.horizon, self.context_len
        return self.u[:, c0 - c:c0], self.y[:, c0 - c:c0], self.u[:, c0:c0 + h], self.y[:, c0:c0 + h]

    def rows(self, index) -> "Window":
        """The windows ``index`` (a mask, indices or a slice) selects, every per-window array alike."""
        def pick(a):
            return a[index] if a is not None and len(a) == len(self.u) else a

        return replace(self, u=self.u[index], y=self.y[index], params=pick(self.params), starts=pick(self.starts),
                       y_first=pick(self.y_first))

    def cut(self, context_len: int | None = None, horizon: int | None = None) -> "Window":
        """The same windows with a shorter context (its last ``context_len`` steps) and/or a
        shorter horizon (its first ``horizon`` steps): the query still starts at the same sample."""
        c, h, c0 = context_len or self.context_len, horizon or self.horizon, self.context_len
        if not (1 <= c <= c0 and 1 <= h <= self.horizon):
            raise WindowError(f"cut to context {c} and horizon {h}: both must lie within the window's "
                              f"{c0} + {self.horizon} steps")
        rows = slice(c0 - c, c0 + h)
        return replace(self, u=self.u[:, rows], y=self.y[:, rows], context_len=c, horizon=h)


def parse_offset(text: str | int | None) -> str | int:
    """``start`` (or None), ``random``, or a non-negative step: the ``--offset`` option.

    Raises:
        WindowError: anything else.
    """
    if text is None or (isinstance(text, str) and text.strip().lower() in ("", "start", "0")):
        return "start"
    if isinstance(text, str) and text.strip().lower() == "random":
        return "random"
    try:
        value = int(text)
    except (TypeError, ValueError):
        raise WindowError(f"--offset takes 'start', 'random' or a step number >= 0, got {text!r}") from None
    if value < 0:
        raise WindowError(f"--offset must be >= 0, got {value}")
    return value or "start"


def window_starts(offset: str | int, n: int, steps: int, length: int, seed: int = 0) -> np.ndarray:
    """The first step of each of ``n`` windows of ``length`` steps in trajectories of ``steps``.

    ``random`` draws each start uniformly from every start that keeps the window inside
    the trajectory, from a stream of its own under ``seed`` (``SeedSequence(seed)``'s
    first child, so other uses of the same seed draw independently).

    Raises:
        WindowError: a fixed offset that pushes the window past the end of the data.
    """
    room = steps - length  # the largest start that still fits
    if offset == "start":
        return np.zeros(n, dtype=np.int64)
    if offset == "random":
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
        return rng.integers(0, room + 1, size=n).astype(np.int64)
    if int(offset) > room:
        raise WindowError(f"--offset {offset} + context_len + horizon = {int(offset) + length} steps exceeds the "
                          f"store's T={steps}: use an offset <= {room} or a shorter window")
    return np.full(n, int(offset), dtype=np.int64)


def cut(a: np.ndarray, starts: np.ndarray, length: int) -> np.ndarray:
    """``a[i, starts[i]:starts[i] + length]`` for every row ``i`` of ``a`` (N, T, C)."""
    idx = starts[:, None] + np.arange(length)[None, :]
    return a[np.arange(len(a))[:, None], idx]


def load_window(data: str, context_len: int, horizon: int, n: int | None, info: dict | None,
                n_u: int, n_y: int, offset: str | int = "start", seed: int = 0, inputs: str = "total",
                rows: np.ndarray | None = None) -> Window:
    """Reads and checks the first ``n`` trajectories of a store (of ``rows``, when given: trajectory
    indices, e.g. a checkpoint's validation split) against the model.

    ``inputs`` picks the input array (``total``: ``u``, ``command``: ``u_cmd``); a store
    without the command is refused with a message saying to regenerate it.

    Raises:
        ValueError: empty store, channels that differ from the checkpoint's, a window longer
            than the trajectories, or non-finite values (the trajectories are named).
    """
    from robomorph.data.store import open_store  # noqa: PLC0415

    ds = open_store(data, allow_incomplete=True)
    total = int(ds.attrs.get("n", 0))
    if total == 0:
        raise WindowError(f"{data} holds no trajectories: generate or import data into it first")
    ds = open_store(data)  # a half-written store: the error says how to finish it
    u_names = ds.input_names(inputs)
    if info is not None:
        for what, ours, theirs in (("u_names", u_names, info["u_names"]), ("y_names", ds.y_names, info["y_names"])):
            if info.get("channel_mask"):  # a model of several arms: the store's channels by name, padded
                columns(ours, theirs, what, data)
            elif list(ours) != list(theirs):
                raise WindowError(f"{data} has {what} {list(ours)} but the checkpoint was trained on {list(theirs)}")
        # A model learns the dynamics per step: at another sample time it predicts another robot.
        if info.get("dt") and abs(ds.dt - float(info["dt"])) > 1e-6 * float(info["dt"]):
            raise WindowError(f"{data} is sampled at dt={ds.dt:.6g} s but the checkpoint was trained at "
                              f"dt={float(info['dt']):.6g} s; resample the logs to the training rate "
                              "(robomorph ingest --resample HZ) or train on data at this rate")
    elif (len(ds.u_names), len(ds.y_names)) != (n_u, n_y):
        raise WindowError(f"{data} has n_u={len(ds.u_names)}, n_y={len(ds.y_names)} but the checkpoint expects "
                          f"n_u={n_u}, n_y={n_y}")
    length = context_len + horizon
    if context_len < 1 or horizon < 1 or length > ds.steps:
        raise WindowError(f"context_len {context_len} + horizon {horizon} must fit in the store's T={ds.steps} steps "
                          "(both >= 1): pass shorter --context-len / --horizon")
    if rows is None:
        rows = slice(0, min(n or total, total))
    else:
        rows = np.asarray(rows, dtype=np.int64)[:n]
        if len(rows) == 0 or rows.min() < 0 or rows.max() >= total:
            raise WindowError(f"{data}: trajectory rows must be non-empty and within 0..{total - 1}")
    u, y = ds.read_inputs(inputs, rows), ds.read("y", rows)
    starts = window_starts(offset, len(u), ds.steps, length, seed)
    y_first = y[:, 0].copy()
    u, y = cut(u, starts, length), cut(y, starts, length)
    bad = np.flatnonzero(~(np.isfinite(u).all((1, 2)) & np.isfinite(y).all((1, 2))))
    if len(bad):
        raise WindowError(f"{data}: trajectories {bad[:10].tolist()} hold NaN or inf in the evaluated window; "
                          "drop them (robomorph.merge) or fix the import")
    return Window(u, y, context_len, horizon, list(u_names), list(ds.y_names), ds.dt, ds.attrs,
                  ds.read("params", rows), starts, y_first, inputs)


def parse_range(text: str | None, low: int, high: int, what: str) -> list[int]:
    """``a:b:s`` (b included) or ``a,b,c`` into a list within ``[low, high]``."""
    if not text:
        return []
    try:
        if ":" in text:
            a, b, s = (int(v) for v in text.split(":"))
            values = list(range(a, b + 1, s))
        else:
            values = [int(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--sweep-{what} takes start:stop:step or a comma list of integers, got {text!r}") from None
    if not values or min(values) < low or max(values) > high:
        raise ValueError(f"--sweep-{what} {text!r} must lie within [{low}, {high}]")
    return values


class EvaluationError(RoboMorphError, ValueError):
    """Evaluation settings that cannot work; the message names the flag."""


def check_counts(**values: int | None) -> None:
    """Refuses a given (not None) step or trajectory count below 1: ``--context-len 0`` would
    otherwise fall back to the checkpoint's length without a word."""
    for name, value in values.items():
        if value is not None and value < 1:
            flag = "--" + name.replace("_", "-")
            raise EvaluationError(f"{flag} {value}: give a positive number, or leave it out for the default")


def check_patch(patch: int, contexts: list[int]) -> None:
    """Refuses contexts the model cannot tokenize (not whole patches)."""
    odd = [c for c in contexts if c % patch]
    if odd:
        raise ValueError(f"context lengths must be multiples of the model's patch ({patch} steps per token): "
                         f"{odd} are not (--context-len / --sweep-context)")


def start_joints(w: Window, n_joint: int = 7) -> np.ndarray | None:
    """(N, n_joint) the joint positions where each window's trajectory started (its joint springs'
    rest pose, as the generator anchored them: what the physics baselines and a hybrid model are
    given), or None where every window opens its trajectory (the context's first sample is then
    that pose) or the outputs hold no joints q0..q{n_joint-1}."""
    names = [f"q{i}" for i in range(n_joint)]
    if not w.starts.any() or w.y_first is None or not set(names) <= set(w.y_names):
        return None
    return w.y_first[:, [w.y_names.index(n) for n in names]].astype(np.float64)


def recipe_note(physics: dict | None, attrs: dict) -> str | None:
    """One line where a hybrid (its backbone record ``physics``) is scored on a simulated store (``attrs``) whose
    arm compensated its gravity otherwise than the recipe the hybrid was made for: it then identifies and
    simulates another command than the store's (issue 61: 0.15 against 0.086 mrad at step 1, said nowhere).
    None where they agree, or where either is no simulated recipe (a real log, a decoder)."""
    recipe = (physics or {}).get("recipe") or {}
    config = attrs.get("config") if isinstance(attrs.get("config"), dict) else {}
    if not recipe or attrs.get("task") in (None, "ingested") or not config:
        return None
    # A recipe's dict leaves out nothing but the robot; "true_model" for records that predate the field.
    mine, theirs = (str(r.get("gravity_compensation", "true_model")) for r in (recipe, config))
    if mine == theirs:
        return None
    return (f"recipe: the hybrid was made for gravity compensation {mine!r} and this store's robots were simulated "
            f"with {theirs!r}, so its commands are another arm's; score it on a store of its own recipe")
