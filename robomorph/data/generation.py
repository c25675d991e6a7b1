"""``python -m robomorph.generate``: randomized robot-arm trajectories into a Zarr dataset.

Attempts are numbered; attempt ``i`` is fully determined by (recipe, seed, i). The kept
trajectories are the first ``robots`` valid attempts in index order, so the arrays are
identical whatever the worker count or batch size. Rows are flushed in chunks together
with a resume cursor, so a killed run continues with the same command and ends with the
same arrays as an uninterrupted one.
"""

from __future__ import annotations

import collections
import math
import multiprocessing as mp
import os
import signal
import sys
import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from robomorph.core.config import ConfigError
from robomorph.core.errors import OutputExistsError, RoboMorphError
from robomorph.core.locks import exclusive_on
from robomorph.core.progress import Phase
from robomorph.data.store import STATUS_COMPLETE, DatasetWriter, SchemaError, create_store, open_store
from robomorph.data import real_logs
from robomorph.sim import episode, kinematics, realism
from robomorph.sim.filters import REASONS
from robomorph.sim.open_loop import OpenLoopEngine
from robomorph.sim.randomize import param_names
from robomorph.sim.recipe import Recipe

# Below this kept rate (after MIN_ATTEMPTS_FOR_RATE attempts) the bound on attempts can
# never be met, so the run stops early instead of burning hours.
MIN_ATTEMPTS_FOR_RATE = 256


# What u - u_cmd is in each gravity mode (recorded in the store's attributes).
_COMPENSATION = {"true_model": "g(q) of the robot's own (randomized) model, added by its actuators",
                 "nominal_model": "g(q) of the catalogue (un-randomized) robot, added by the controller",
                 "none": "nothing: u_cmd equals u"}


class GenerationError(RoboMorphError, RuntimeError):
    """Generation cannot reach its target (e.g. the valid rate is too low)."""


@dataclass(frozen=True)
class Shard:
    """Part ``index`` of ``count``: attempt slots j map to attempt index + count * j."""

    index: int = 0
    count: int = 1

    @classmethod
    def parse(cls, text: str) -> "Shard":
        try:
            i, n = (int(x) for x in text.split("/"))
        except ValueError as exc:
            raise ConfigError(f"--shard must look like i/n (e.g. 0/4), got {text!r}") from exc
        if not 0 <= i < n:
            raise ConfigError(f"--shard {text}: need 0 <= i < n")
        return cls(i, n)

    def robots(self, total: int) -> int:
        return total // self.count + (self.index < total % self.count)

    def attempt(self, slot: int) -> int:
        return self.index + self.count * slot


@dataclass
class _Progress:
    """Committed state (on disk) plus the outcomes processed beyond it (in memory)."""

    target: int
    cursor: int = 0  # attempt slots committed
    kept: int = 0
    rejected: dict[str, int] = field(default_factory=lambda: {r: 0 for r in REASONS})
    pending: list = field(default_factory=list)  # (slot, Outcome) after the cursor

    def attrs(self) -> dict:
        return {"cursor": self.cursor, "attempted": self.cursor, "kept": self.kept,
                "rejected": dict(self.rejected)}

    def take(self, k: int) -> list:
        """Commits the next ``k`` kept outcomes, and the rejections before them."""
        rows, i = [], 0
        while len(rows) < k:
            slot, out = self.pending[i]
            i += 1
            if out.reason is None:
                rows.append(out)
            else:
                self.rejected[out.reason] += 1
            self.cursor = slot + 1
        del self.pending[:i]
        self.kept += k
        return rows

    def pending_kept(self) -> int:
        return sum(out.reason is None for _, out in self.pending)


def _extras(recipe: Recipe) -> dict:
    extras = {"attempt": ((), "int64"), "task_index": ((), "int8"), "fm": ((), "float32")}
    if recipe.has_osc:
        extras.update(kp=((), "float32"), target=((recipe.steps, 3), "float32"))
    if recipe.realism.enabled:
        extras["realism"] = ((len(realism.names(recipe.arm.n_joint)),), "float32")
    return extras


def _rows(recipe: Recipe, outs: list) -> tuple:
    tasks = recipe.task_names
    extras = {"attempt": np.array([o.index for o in outs], dtype=np.int64),
              "task_index": np.array([tasks.index(o.task) for o in outs], dtype=np.int8),
              "fm": np.array([o.fm for o in outs], dtype=np.float32)}
    if recipe.has_osc:
        extras["kp"] = np.array([o.kp for o in outs], dtype=np.float32)
        nan = np.full((recipe.steps, 3), np.nan, dtype=np.float32)
        extras["target"] = np.stack([nan if o.target is None else o.target for o in outs])
    if recipe.realism.enabled:
        extras["realism"] = np.stack([o.realism for o in outs]).astype(np.float32)
    u = np.stack([o.u for o in outs])
    extras["u_cmd"] = np.stack([o.u_cmd for o in outs])
    y = np.stack([o.y for o in outs])
    params = np.stack([o.params for o in outs]).astype(np.float32)
    return u, y, params, extras


def _open_writer(recipe: Recipe, out: str, shard: Shard, overwrite: bool) -> DatasetWriter | None:
    """Creates the store, or reopens a matching unfinished one; None if already complete."""
    target = shard.robots(recipe.robots)
    if os.path.isdir(out) and os.listdir(out) and not overwrite:
        try:
            ds = open_store(out, allow_incomplete=True)
        except SchemaError as exc:
            raise OutputExistsError(f"{out} exists and is not a RoboMorph dataset; refusing to touch it") from exc
        a = ds.attrs
        if a.get("config") != recipe.to_dict() or a.get("shard") != [shard.index, shard.count]:
            raise OutputExistsError(
                f"{out} holds a dataset made with a different recipe, seed or shard; "
                "pass --overwrite to replace it, or choose another --out"
            )
        if a["status"] == STATUS_COMPLETE:
            return None
        if "u_cmd" not in ds.arrays:
            raise FileExistsError(f"{out} is an unfinished store of schema {a.get('schema_version')} (no u_cmd): "
                                  "it cannot be resumed by this version; pass --overwrite to start it again")
        return DatasetWriter.reopen(out)
    arm = recipe.arm
    attrs = {
        "dt": recipe.dt, "domain": arm.name, "task": recipe.task_label, "task_names": recipe.task_names,
        "config": recipe.to_dict(), "seed": recipe.seed, "requested": target,
        "shard": [shard.index, shard.count], "substeps": recipe.substeps,
        "gravity_compensation": recipe.gravity_compensation,
        "u_cmd_compensation": _COMPENSATION[recipe.gravity_compensation],
        "cursor": 0, "attempted": 0, "kept": 0, "rejected": {r: 0 for r in REASONS},
    }
    if arm.name != "panda":  # (the Panda's attributes, hence its stores' fingerprints, stay as they were)
        attrs.update(robot=arm.title, joint_names=list(arm.joint_names),
                     torque_limits=[float(x) for x in arm.limits])
    if recipe.realism.enabled:  # (the terms themselves are in config["realism"])
        attrs["realism_names"] = realism.names(arm.n_joint)
        if recipe.realism.timing.log_physics_rate:
            attrs["original_dt"] = recipe.dt / recipe.substeps
    return create_store(out, target, recipe.steps, list(arm.u_names), list(arm.y_names),
                        param_names(arm.name), attrs, extras=_extras(recipe), chunk=recipe.chunk,
                        overwrite=overwrite, u_cmd_names=list(arm.u_cmd_names))


class _Engines:
    """Open-loop rollout threads and closed-loop worker processes, made on first use."""

    def __init__(self, recipe: Recipe, workers: int):
        self.recipe, self.workers = recipe, workers
        self.model = episode.build_model(recipe)
        self.randomizer = episode.make_randomizer(self.model, recipe)
        self._open: OpenLoopEngine | None = None
        self._pool = None
        self._local: episode.ClosedLoopRunner | None = None

    def open_loop(self, indices: list[int]) -> list:
        r = self.recipe
        if self._open is None:
            self._open = OpenLoopEngine(self.model, self.workers, r.substeps)
        draws = [episode.draw(r, self.randomizer, i) for i in indices]
        sens, ranges = self._open.run(lambda model, i: self.randomizer.apply(model, draws[i].params),
                                      np.stack([d.qpos0 for d in draws]), np.stack([d.ctrl for d in draws]))
        return [episode.finish(r, d, s, jr[: r.arm.n_joint], r.substeps, model=self.model)
                for d, s, jr in zip(draws, sens, ranges)]

    def closed_loop(self, indices: list[int]) -> list:
        if self.workers == 1:
            self._local = self._local or episode.ClosedLoopRunner(self.recipe)
            return [self._local(i) for i in indices]
        if self._pool is None:
            # spawn, not fork: the parent may hold MuJoCo rollout threads.
            ctx = mp.get_context("spawn")
            self._pool = ctx.Pool(self.workers, initializer=_init_worker, initargs=(self.recipe,))
        return self._pool.map(_run_worker, indices, chunksize=max(1, len(indices) // (4 * self.workers)))

    def close(self) -> None:
        if self._open is not None:
            self._open.close()
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()


_WORKER: episode.ClosedLoopRunner | None = None


def _init_worker(recipe: Recipe) -> None:
    global _WORKER
    # A Ctrl-C reaches every process of the terminal: the parent stops the run, workers say nothing.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER = episode.ClosedLoopRunner(recipe)


def _run_worker(index: int):
    return _WORKER(index)


def _simulate(engines: _Engines, recipe: Recipe, indices: list[int]) -> list:
    """Outcomes of a batch, in index order, each attempt through its engine."""
    tasks = {i: episode.draw_task(recipe, i) for i in indices}
    open_idx = [i for i in indices if episode.is_open_loop(recipe, tasks[i])]
    closed_idx = [i for i in indices if not episode.is_open_loop(recipe, tasks[i])]
    outs = {}
    if open_idx:
        outs.update((o.index, o) for o in engines.open_loop(open_idx))
    if closed_idx:
        outs.update((o.index, o) for o in engines.closed_loop(closed_idx))
    if recipe.realism.timing.log_physics_rate:
        for o in outs.values():
            _to_model_rate(recipe, engines.model, o)
    return [outs[i] for i in indices]


def _to_model_rate(recipe: Recipe, model, out: episode.Outcome) -> None:
    """Brings a row logged at the physics rate to ``dt`` through ingest's anti-aliasing resampler
    (:func:`robomorph.data.real_logs.resample`), as a real 1 kHz log is brought to the model's
    rate; the EE pose is the catalogue kinematics of the resampled joints, as ``ingest --layout``
    computes it."""
    if out.reason is not None:
        return
    h, hz = recipe.dt / recipe.substeps, 1.0 / recipe.dt
    out.u = real_logs.resample(out.u, h, hz)
    out.u_cmd = real_logs.resample(out.u_cmd, h, hz)
    q = real_logs.resample(out.y[:, 7:], h, hz).astype(np.float64)
    out.y = np.concatenate([kinematics.ee_pose(q, model), q], axis=1).astype(np.float32)


def _max_attempts(recipe: Recipe, target: int) -> int:
    return math.ceil(target * recipe.max_attempts_factor)


def _check_rate(recipe: Recipe, prog: _Progress, processed: int, target: int) -> None:
    kept = prog.kept + prog.pending_kept()
    rejected = collections.Counter(prog.rejected)
    rejected.update(out.reason for _, out in prog.pending if out.reason)
    too_many = processed >= _max_attempts(recipe, target)
    hopeless = processed >= MIN_ATTEMPTS_FOR_RATE and kept < processed / recipe.max_attempts_factor
    if too_many or hopeless:
        raise GenerationError(
            f"valid rate too low: kept {kept} of {processed} attempts "
            f"(rejected: {dict(+rejected)}); the bound is {recipe.max_attempts_factor:g} attempts per "
            "kept trajectory. Make the torques gentler (signal.scale), raise damping/stiffness, "
            "loosen the filters, or raise max_attempts_factor. The store keeps what was committed "
            "and re-running the same command resumes it."
        )


@exclusive_on("out")  # one writer per store: two would mix their robots in one store
def generate(recipe: Recipe, out: str, workers: int | None = None, shard: Shard = Shard(),
             overwrite: bool = False, progress: bool = True) -> dict:
    """Generates (or resumes, or finds complete) the dataset of ``recipe`` at ``out``.

    Args:
        recipe: the validated recipe.
        out: store directory.
        workers: threads for rollouts and processes for closed loops (default: all cores).
        shard: which disjoint part of the attempts to generate.
        overwrite: replace an existing RoboMorph store at ``out``.
        progress: show a progress bar on stderr.

    Returns:
        The store's final attributes.
    """
    workers = max(1, workers or os.cpu_count() or 1)
    writer = _open_writer(recipe, out, shard, overwrite)
    if writer is None:
        return open_store(out).attrs
    a = writer.attrs
    prog = _Progress(target=int(a["capacity"]), cursor=int(a["cursor"]), kept=int(a["n"]),
                     rejected={r: int(a["rejected"].get(r, 0)) for r in REASONS})
    engines = _Engines(recipe, workers)
    # A bar on a terminal; in a log, where its redraws would pile up on one line, a line every few seconds.
    log = progress and not sys.stderr.isatty()
    bar = tqdm(total=prog.target, initial=prog.kept, unit="traj", desc=f"generate {recipe.task_label}",
               disable=not progress or log, mininterval=1.0, dynamic_ncols=True)
    slot, t0, made = prog.cursor, time.time(), 0
    with Phase(f"generate {recipe.task_label}", prog.target, "robot", enabled=log, initial=prog.kept) as lines:
        try:
            while prog.kept < prog.target:
                _check_rate(recipe, prog, slot, prog.target)
                slots = list(range(slot, slot + recipe.chunk))
                outs = _simulate(engines, recipe, [shard.attempt(s) for s in slots])
                prog.pending.extend(zip(slots, outs))
                slot += len(slots)
                made += len(slots)
                _flush(writer, recipe, prog)
                kept_now = prog.kept + prog.pending_kept()
                bar.n = min(kept_now, prog.target)
                bar.set_postfix_str(_postfix(prog, slot, made, time.time() - t0), refresh=False)
                bar.refresh()
                lines.note = _postfix(prog, slot, made, time.time() - t0)
                lines.update(min(kept_now, prog.target) - lines.n)
        finally:
            bar.close()
            engines.close()
    writer.finalize(**prog.attrs())
    return open_store(out).attrs


def _flush(writer: DatasetWriter, recipe: Recipe, prog: _Progress) -> None:
    """Writes full chunks (and the final partial one) with the matching cursor."""
    while True:
        need = prog.target - prog.kept
        k = min(recipe.chunk, need)
        if k == 0 or prog.pending_kept() < k:
            return
        rows = prog.take(k)
        u, y, params, extras = _rows(recipe, rows)
        writer.append(u, y, params, extras=extras, progress=prog.attrs())


def _postfix(prog: _Progress, slot: int, made: int, elapsed: float) -> str:
    rejected = collections.Counter({k: v for k, v in prog.rejected.items() if v})
    rejected.update(out.reason for _, out in prog.pending if out.reason)
    kept = prog.kept + prog.pending_kept()
    rate = made / elapsed if elapsed > 0 else 0.0
    rej = " ".join(f"{k}={v}" for k, v in sorted(rejected.items())) or "none"
    return f"attempted={slot} kept={kept} ({kept / max(slot, 1):.0%}) rejected: {rej} | {rate:.1f} attempts/s"
