"""The open-loop engine: every physics step recorded, robots independent of their batch."""

import numpy as np

from robomorph.sim import panda
from robomorph.sim.open_loop import OpenLoopEngine


def _torques(n, frames, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, size=(n, frames, panda.N_JOINT))


def test_a_robot_rolls_out_the_same_alone_or_in_a_batch_of_groups(nominal_model):
    ctrl = _torques(3, 12)
    qpos0 = np.tile(panda.HOME_QPOS, (3, 1)) + np.linspace(0, 0.05, 3)[:, None]
    damping = [0.5, 1.0, 2.0]

    def randomize(model, i):  # a different robot per row, written into the engine's copy
        model.dof_damping[: panda.N_JOINT] = damping[i]

    with OpenLoopEngine(nominal_model, 1, 4, group=2) as eng:  # two groups: rows 0-1, then row 2
        sens, ranges = eng.run(randomize, qpos0, ctrl)
        batch = sens.copy()
    assert batch.shape == (3, 12 * 4, nominal_model.nsensordata) and len(ranges) == 3
    with OpenLoopEngine(nominal_model, 1, 4) as eng:
        alone, _ = eng.run(lambda m, i: randomize(m, 2), qpos0[2:], ctrl[2:])
        np.testing.assert_array_equal(batch[2], alone[0])
    assert not np.allclose(batch[0], batch[1])  # the robots differ, so the rows do


def test_rollouts_without_mujocos_checks_equal_the_checked_ones_and_odd_arrays_keep_the_checks(nominal_model):
    """ThreadedRollout skips mujoco.rollout's Python checks only where its arrays are already what the C++ reads:
    then the states are the checked call's to the bit; arrays of another shape or kind keep the checks (and the
    checked call's error), never reach the C++ unchecked."""
    import copy

    import mujoco
    import pytest

    from robomorph.sim.open_loop import ThreadedRollout, _unchecked

    models = [copy.deepcopy(nominal_model) for _ in range(2)]
    models[1].dof_damping[:] = 3.0
    n, steps = 4, 6
    size = mujoco.mj_stateSize(nominal_model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    data = mujoco.MjData(nominal_model)
    data.qpos[:panda.N_JOINT] = panda.HOME_QPOS
    x0 = np.empty(size)
    mujoco.mj_getState(nominal_model, data, x0, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    x0 = np.tile(x0, (n, 1))
    ctrl = np.ascontiguousarray(_torques(n, steps, seed=3))
    rows = [models[k % 2] for k in range(n)]
    assert _unchecked(rows, x0, ctrl, {"state": np.empty((n, steps, size))})["skip_checks"]
    for threads in (1, 2):
        fast, checked = np.empty((n, steps, size)), np.empty((n, steps, size))
        roll = ThreadedRollout(nominal_model, threads)
        roll(rows, x0, ctrl, state=fast)
        mujoco.rollout.rollout(rows, roll.datas, x0, ctrl, state=checked)
        np.testing.assert_array_equal(fast, checked)
        roll.close()
    assert not np.allclose(fast[0], fast[1])  # the two robots differ, so the rows do
    for bad in ({"state": np.empty((n, steps + 1, size))}, {"state": np.empty((n, steps, size), dtype=np.float32)},
                {"state": np.empty((n, steps, size))[:, ::-1]}, {}):
        assert _unchecked(rows, x0, ctrl, bad) == {}
    assert _unchecked(rows[:3], x0, ctrl, {"state": np.empty((n, steps, size))}) == {}
    with pytest.raises(ValueError):  # the checked call's own error
        ThreadedRollout(nominal_model, 1)(rows[:3], x0, ctrl, state=np.empty((n, steps, size)))
