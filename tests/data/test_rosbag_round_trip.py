"""The round trip of issue 64: a URDF arm simulated, its trajectories written as ROS1 and ROS2
bags by rosbags' own writers, ingested, and predicted: the figures equal those on the store
``generate`` wrote directly, window for window, to 1e-6 rad."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph.data.ingest import ingest_rosbag
from robomorph.data.store import open_store
from robomorph.predictor import Predictor
from robomorph.sim import arms, user_arms
from tests.data.bag_factory import bag_path, write_joint_states
from tests.sim.urdf_factory import serial_arm, write

ROBOTS, STEPS, CONTEXT = 2, 160, 80
PAUSE_S = 10.0  # between two trajectories in the bag: --split-gap 5 cuts them apart again


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """The arm registered from a URDF, and a store generate wrote for it (total torques, no
    gravity compensation by the arm: what a torque sensor logs)."""
    from robomorph.data.generation import generate
    from robomorph.sim.recipe import load_recipe

    tmp = tmp_path_factory.mktemp("round_trip")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(arms.USER_ARMS_ENV, str(tmp / "arms"))
        user_arms.add(user_arms.ArmRequest("bagarm", write(tmp / "bagarm.urdf", serial_arm(3, name="bagarm")), "urdf"))
        config = {"robot": "bagarm", "task": "multisine", "robots": ROBOTS, "steps": STEPS, "seed": 5,
                  "gravity_compensation": "none"}
        store = str(tmp / "generated.zarr")
        generate(load_recipe(None, config), store, workers=1, progress=False)
        yield tmp, open_store(store)


def _bag_of(ds, path, kind):
    """Every trajectory of ``ds`` as JointState messages, stamped at the store's rate, a pause between them."""
    u, y = np.asarray(ds.group["u"], np.float64), np.asarray(ds.group["y"], np.float64)
    n_joint = u.shape[2]
    stamps, q, tau = [], [], []
    for i in range(len(u)):
        # Integer nanoseconds: a float of 1.7e18 ns keeps only 256 ns steps.
        start = 1_700_000_000 * 10**9 + round(i * (STEPS * ds.dt + PAUSE_S) * 1e9)
        stamps.append(start + np.round(np.arange(STEPS) * ds.dt * 1e9).astype(np.int64))
        q.append(y[i, :, 7:7 + n_joint])
        tau.append(u[i])
    return write_joint_states(path, kind, np.concatenate(stamps), list(arms.get("bagarm").joint_names),
                              np.concatenate(q), None, np.concatenate(tau))


def _predict(ds):
    pred = Predictor.from_arm("bagarm", inputs="total", gravity_compensation="none", dt=ds.dt)
    u, y = np.asarray(ds.group["u"]), np.asarray(ds.group["y"])
    return pred.simulate(u[:, :CONTEXT], y[:, :CONTEXT], u[:, CONTEXT:], inputs="total", at_rest=True), y[:, CONTEXT:]


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_bags_of_a_urdf_arm_predict_as_its_generated_store(generated, kind):
    tmp, direct = generated
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(arms.USER_ARMS_ENV, str(tmp / "arms"))
        bag = _bag_of(direct, bag_path(tmp, kind, f"bag_{kind}"), kind)
        ingested = ingest_rosbag([str(bag)], str(tmp / f"ingested_{kind}.zarr"), steps=STEPS, split_gap=5.0,
                                 layout="bagarm")
        assert (ingested.n, ingested.steps, ingested.u_names, ingested.y_names) == \
            (direct.n, direct.steps, direct.u_names, direct.y_names)
        assert ingested.dt == pytest.approx(direct.dt, rel=1e-9) and ingested.attrs["arm"] == "bagarm"
        # The same windows: torques and joint angles to the bit (float32 -> float64 -> float32), the
        # pose recomputed from the angles by the arm's kinematics to float32 precision.
        np.testing.assert_array_equal(np.asarray(ingested.group["u"]), np.asarray(direct.group["u"]))
        np.testing.assert_array_equal(np.asarray(ingested.group["y"])[..., 7:], np.asarray(direct.group["y"])[..., 7:])
        np.testing.assert_allclose(np.asarray(ingested.group["y"])[..., :7], np.asarray(direct.group["y"])[..., :7],
                                   atol=1e-6)
        (mine, truth), (theirs, truth2) = _predict(ingested), _predict(direct)
    joints = slice(7, None)
    np.testing.assert_allclose(mine[..., joints], theirs[..., joints], atol=1e-6)
    rmse = [np.sqrt(np.mean((p[..., joints] - t[..., joints]) ** 2)) for p, t in ((mine, truth), (theirs, truth2))]
    assert rmse[0] == pytest.approx(rmse[1], abs=1e-6)
    hold = np.sqrt(np.mean((truth[..., joints] - truth[:, :1, joints]) ** 2))
    assert rmse[0] < hold  # the hybrid on the bag's arm predicts, it is not an identity


def test_evaluate_robot_on_the_bag_store_scores_as_on_the_generated_store(generated, tmp_path):
    """The third command of the page: ``evaluate --robot`` on the ingested bag gives the generated store's figures."""
    from robomorph.evaluation.evaluator import evaluate
    from robomorph.evaluation.requests import EvaluateConfig

    tmp, direct = generated
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(arms.USER_ARMS_ENV, str(tmp / "arms"))
        bag = _bag_of(direct, bag_path(tmp_path, "db3", "bag"), "db3")
        store = str(tmp_path / "ingested.zarr")
        ingest_rosbag([str(bag)], store, steps=STEPS, split_gap=5.0, layout="bagarm")
        results = [evaluate(EvaluateConfig(data=data, arm="bagarm", out=str(tmp_path / name), context_len=CONTEXT,
                                           horizon=STEPS - CONTEXT, baselines=("hold", "constant_velocity",
                                                                               "nominal_physics"),
                                           device="cpu", samples=0, inputs=inputs, stacked=stacked))
                   for data, name, inputs, stacked in ((store, "eval_bag", None, "auto"),
                                                       (direct.path, "eval_direct", "total", "on"))]
    for rows in (lambda r: r["approach1"]["channels"], lambda r: r["baselines"]["nominal_physics"]["approach1"]["channels"],
                 lambda r: r["baselines"]["hold"]["approach1"]["channels"]):
        bag_rows, direct_rows = rows(results[0]), rows(results[1])
        for ch in ("q0", "q1", "q2"):
            assert bag_rows[ch]["rmse"]["mean"] == pytest.approx(direct_rows[ch]["rmse"]["mean"], abs=1e-6), ch
    assert results[0]["meta"]["inputs"] == "total"  # a log's torque is the total one, without being told
    # The bag is a recording: evaluate stacks its model there by default (--stacked auto), as asked on the store
    # generated directly.
    assert results[0]["meta"]["stacked"] and results[1]["meta"]["stacked"]
