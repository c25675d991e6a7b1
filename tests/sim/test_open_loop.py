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
