"""The ``realistic`` recipe through ``generate``: every arm, the store's records, the 1 kHz log path."""

import numpy as np
import pytest

from robomorph.data import generation, real_logs
from robomorph.data.store import open_store
from robomorph.generate import main
from robomorph.sim import arms, episode, kinematics, realism
from robomorph.sim.recipe import load_recipe


@pytest.mark.parametrize("robot", arms.names())
def test_generate_realistic_works_for_every_arm(robot, tmp_path):
    out = str(tmp_path / f"{robot}.zarr")
    assert main(["--config", "realistic", "--robot", robot, "--robots", "2", "--steps", "12",
                 "--workers", "1", "--out", out, "--quiet"]) == 0
    ds = open_store(out)
    n = arms.get(robot).n_joint
    assert ds.attrs["realism_names"] == realism.names(n)
    assert ds.attrs["config"]["realism"] == load_recipe("realistic").to_dict()["realism"]
    assert ds.attrs["gravity_compensation"] == "nominal_model"
    assert ds.dt == pytest.approx(1 / 60) and ds.attrs["original_dt"] == pytest.approx(1 / 960)
    values = ds.read("realism")
    assert values.shape == (2, len(realism.names(n))) and np.all(np.isfinite(values))
    names = realism.names(n)
    latency = values[:, names.index("latency")]
    assert np.all((latency >= 1) & (latency <= 4)) and np.all(latency == np.round(latency))
    assert ds.read("u").shape == (2, 12, n) and np.all(np.isfinite(ds.read("y")))


def test_a_physics_rate_log_is_brought_to_dt_by_ingests_resampler():
    r = load_recipe("realistic", {"steps": 24, "task": "multisine"})
    runner = episode.ClosedLoopRunner(r)
    out = runner(0)
    assert out.reason is None and out.u.shape == (24 * r.substeps, 7)  # every physics step
    full_u, full_q = out.u.copy(), out.y[:, 7:].copy()
    generation._to_model_rate(r, runner.model, out)
    h = r.dt / r.substeps
    np.testing.assert_array_equal(out.u, real_logs.resample(full_u, h, 1 / r.dt))
    np.testing.assert_array_equal(out.y[:, 7:], real_logs.resample(full_q, h, 1 / r.dt))
    assert out.u.shape == (24, 7) and out.u_cmd.shape == (24, 7)
    np.testing.assert_allclose(out.y[:, :7], kinematics.ee_pose(out.y[:, 7:].astype(np.float64), runner.model),
                               atol=1e-6)


def test_sensor_realism_alone_keeps_the_rollout_engine_and_records_its_draws(tmp_path):
    r = load_recipe(None, {"robots": 3, "steps": 20, "realism": {"torque": {"offset": 0.01}}})
    out = str(tmp_path / "s.zarr")
    generation.generate(r, out, workers=1, progress=False)
    ds = open_store(out)
    names = ds.attrs["realism_names"]
    offsets = ds.read("realism")[:, [names.index(f"torque_offset_q{j}") for j in range(7)]]
    assert np.all(np.abs(offsets) <= 0.01 * arms.get("panda").limits + 1e-6) and np.abs(offsets).min() > 0
    # The same robots without the offset: the logged torque differs by exactly the drawn offsets.
    clean = str(tmp_path / "c.zarr")
    generation.generate(load_recipe(None, {"robots": 3, "steps": 20}), clean, workers=1, progress=False)
    np.testing.assert_allclose(ds.read("u") - open_store(clean).read("u"),
                               np.broadcast_to(offsets[:, None, :], (3, 20, 7)), atol=1e-4)
