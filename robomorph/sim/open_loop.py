"""Open-loop batches through ``mujoco.rollout``: many randomized models, all cores busy.

The torque signal is held for each recorded frame (zero-order hold at ``dt``) and the
physics runs ``substeps`` steps per frame. Rollout records sensor data at every physics
step, computed in the forward pass at the start of the step, so frame ``t`` is sample
``t * substeps``: the state at the frame start and the torque applied from it (the same
convention as :mod:`robomorph.sim.closed_loop`). The filters see every physics step.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


class ThreadedRollout:
    """``mujoco.rollout`` over per-thread datas: one call rolls out a batch of models, on a
    thread pool when ``nthread > 1``. Shared by generation and identification."""

    def __init__(self, model: mujoco.MjModel, nthread: int):
        self.datas = [mujoco.MjData(model) for _ in range(nthread)]
        self._pool = rollout.Rollout(nthread=nthread) if nthread > 1 else None

    def __call__(self, models: list, x0: np.ndarray, control: np.ndarray, **out) -> None:
        """Rolls ``models`` out from ``x0`` under ``control``, filling ``out`` (state=, sensordata=)."""
        fast = _unchecked(models, x0, control, out)
        if self._pool is None:
            rollout.rollout(models, self.datas[0], x0, control, **fast, **out)
        else:
            self._pool.rollout(models, self.datas, x0, control, **fast, **out)

    @property
    def nthread(self) -> int:
        return len(self.datas)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None


def _unchecked(models, x0: np.ndarray, control: np.ndarray, out: dict) -> dict:
    """``mujoco.rollout``'s options that skip its checks where this call's arrays are already what its C++ reads
    (one model per row, C-contiguous doubles of the right shapes, every output given); else none. Its checks
    compare each model's state size in Python: over a planner's ~3,000 one-frame rollouts, about 1 ms a call."""
    state, sens = out.get("state"), out.get("sensordata")
    arrays = [a for a in (x0, control, state, sens) if a is not None]
    if state is None or not isinstance(models, list) or not all(
            isinstance(a, np.ndarray) and a.dtype == np.float64 and a.flags.c_contiguous for a in arrays):
        return {}
    n, nstep = control.shape[:2] if control.ndim == 3 else (0, 0)
    m = models[0] if models else None
    if m is None or len(models) != n or x0.shape != (n, mujoco.mj_stateSize(m, _STATE_SPEC)) \
            or control.shape[2] != m.nu or state.shape != (n, nstep, x0.shape[1]) \
            or (sens is not None and sens.shape != (n, nstep, m.nsensordata)) \
            or any(k.nq != m.nq or k.nv != m.nv or k.nu != m.nu or k.na != m.na or k.nsensordata != m.nsensordata
                   for k in {id(k): k for k in models}.values()):  # a few distinct models, each repeated
        return {}
    return {"skip_checks": True, "nstep": nstep}


class OpenLoopEngine:
    """Reusable models, datas, thread pool and buffers for batches of open-loop rollouts.

    A compiled Panda holds ~28 MB of mesh data, so the engine keeps only ``group`` model
    copies (two per thread by default) and rolls a batch out group by group, randomizing
    the copies in place before each group. Memory stays flat whatever the batch size.
    """

    def __init__(self, model: mujoco.MjModel, nthread: int, substeps: int, group: int | None = None):
        if nthread < 1 or substeps < 1:
            raise ValueError(f"nthread and substeps must be >= 1, got {nthread}, {substeps}")
        group = group or 2 * nthread
        self.models = [copy.deepcopy(model) for _ in range(group)]
        self._rollout = ThreadedRollout(model, nthread)
        self._scratch = mujoco.MjData(model)
        self.substeps = substeps
        self.nthread = nthread
        self._state = np.empty(0)
        self._sens = np.empty(0)

    def close(self) -> None:
        self._rollout.close()

    def __enter__(self) -> "OpenLoopEngine":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def initial_state(self, model: mujoco.MjModel, qpos0: np.ndarray) -> np.ndarray:
        """Full physics state at rest in joint configuration ``qpos0``."""
        d = self._scratch
        mujoco.mj_resetData(model, d)
        d.qpos[: len(qpos0)] = qpos0
        state = np.empty(mujoco.mj_stateSize(model, _STATE_SPEC))
        mujoco.mj_getState(model, d, state, _STATE_SPEC)
        return state

    def _buffers(self, n: int, nstep: int) -> tuple[np.ndarray, np.ndarray]:
        m, g = self.models[0], len(self.models)
        if self._sens.shape[:2] != (max(n, len(self._sens)), nstep) or len(self._sens) < n:
            self._state = np.empty((g, nstep, mujoco.mj_stateSize(m, _STATE_SPEC)))
            self._sens = np.empty((n, nstep, m.nsensordata))
        return self._state, self._sens[:n]

    def run(self, randomize: Callable[[mujoco.MjModel, int], None], qpos0: np.ndarray,
            ctrl: np.ndarray) -> tuple[np.ndarray, list[np.ndarray]]:
        """Rolls out ``len(ctrl)`` randomized robots.

        Args:
            randomize: ``randomize(model, i)`` writes robot ``i``'s parameters into a copy.
            qpos0: (n, nq) initial joint positions, at rest.
            ctrl: (n, T, nu) torque commands per recorded frame.

        Returns:
            Sensor data (n, T * substeps, nsensordata) at every physics step (a view of a
            reused buffer, valid until the next call) and each robot's joint ranges.
        """
        n, frames = len(ctrl), np.shape(ctrl)[1]
        state, sens = self._buffers(n, frames * self.substeps)
        ranges = []
        for start in range(0, n, len(self.models)):
            rows = range(start, min(start + len(self.models), n))
            models = self.models[: len(rows)]
            for model, i in zip(models, rows):
                randomize(model, i)
                ranges.append(model.jnt_range.copy())
            x0 = np.stack([self.initial_state(m, qpos0[i]) for m, i in zip(models, rows)])
            control = np.repeat(np.asarray(ctrl[rows.start:rows.stop], dtype=np.float64), self.substeps, axis=1)
            out = dict(state=state[: len(rows)], sensordata=sens[rows.start:rows.stop])
            self._rollout(models, x0, control, **out)
        return sens, ranges
