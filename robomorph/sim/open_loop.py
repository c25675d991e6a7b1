"""Open-loop batches through ``mujoco.rollout``: many randomized models, all cores busy.

The torque signal is held for each recorded frame (zero-order hold at ``dt``) and the
physics runs ``substeps`` steps per frame. Rollout records sensor data at every physics
step, computed in the forward pass at the start of the step, so frame ``t`` is sample
``t * substeps``: the state at the frame start and the torque applied from it (the same
convention as :mod:`robomorph.sim.closed_loop`). The filters see every physics step.
"""

from __future__ import annotations

import copy

import mujoco
import numpy as np
from mujoco import rollout

_STATE_SPEC = mujoco.mjtState.mjSTATE_FULLPHYSICS


class OpenLoopEngine:
    """Reusable models, datas, thread pool and output buffers for batches of rollouts."""

    def __init__(self, model: mujoco.MjModel, batch: int, nthread: int, substeps: int):
        if batch < 1 or nthread < 1 or substeps < 1:
            raise ValueError(f"batch, nthread and substeps must be >= 1, got {batch}, {nthread}, {substeps}")
        # deepcopy costs ~27 ms a model (meshes); models are kept and overwritten in place.
        self.models = [copy.deepcopy(model) for _ in range(batch)]
        self.datas = [mujoco.MjData(model) for _ in range(nthread)]
        self._scratch = mujoco.MjData(model)
        self.substeps = substeps
        self.nthread = nthread
        self._pool = rollout.Rollout(nthread=nthread) if nthread > 1 else None
        self._buffers: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
            self._pool = None

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

    def _outputs(self, nbatch: int, nstep: int) -> tuple[np.ndarray, np.ndarray]:
        key = nstep
        if key not in self._buffers or self._buffers[key][0].shape[0] < nbatch:
            m = self.models[0]
            nstate = mujoco.mj_stateSize(m, _STATE_SPEC)
            batch = len(self.models)
            self._buffers = {key: (np.empty((batch, nstep, nstate)), np.empty((batch, nstep, m.nsensordata)))}
        state, sens = self._buffers[key]
        return state[:nbatch], sens[:nbatch]

    def run(self, n: int, qpos0: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
        """Rolls out the first ``n`` models (already randomized by the caller).

        Args:
            n: number of trajectories (<= batch).
            qpos0: (n, nq) initial joint positions, at rest.
            ctrl: (n, T, nu) torque commands per recorded frame.

        Returns:
            (n, T * substeps, nsensordata) sensor data at every physics step; a view of
            a reused buffer, valid until the next call.
        """
        if not 1 <= n <= len(self.models):
            raise ValueError(f"n must be in [1, {len(self.models)}], got {n}")
        models = self.models[:n]
        x0 = np.stack([self.initial_state(m, q) for m, q in zip(models, qpos0)])
        control = np.repeat(np.asarray(ctrl, dtype=np.float64), self.substeps, axis=1)
        nstep = control.shape[1]
        state, sens = self._outputs(n, nstep)
        if self._pool is None:
            rollout.rollout(models, self.datas[0], x0, control, state=state, sensordata=sens)
        else:
            self._pool.rollout(models, self.datas, x0, control, state=state, sensordata=sens)
        return sens
