import json
import os

from robomorph.data.store import open_store
from robomorph.reproduction.skip import ensure_store, eval_fresh, mark_finished, run_finished, store_state
from robomorph.sim.recipe import load_recipe


def _recipe(seed):
    return load_recipe(None, {"task": "multisine", "robots": 4, "steps": 20, "seed": seed, "chunk": 4})


def test_ensure_store_keeps_a_complete_store_and_replaces_a_stale_one(tmp_path):
    path = str(tmp_path / "s.zarr")
    assert ensure_store(_recipe(1), path, workers=1, progress=False) == "missing"
    y = open_store(path).read("y")
    assert store_state(path, _recipe(1)) == "complete"
    assert ensure_store(_recipe(1), path, workers=1, progress=False) == "complete"
    assert ensure_store(_recipe(2), path, workers=1, progress=False) == "stale"
    assert open_store(path).attrs["seed"] == 2 and (open_store(path).read("y") != y).any()
    (tmp_path / "foreign").mkdir()
    assert store_state(str(tmp_path / "foreign"), _recipe(1)) == "missing"  # not ours: never overwritten


def test_run_and_evaluation_markers(tmp_path):
    ckpt = tmp_path / "best.ckpt"
    ckpt.write_bytes(b"x")
    budget = {"max_steps": 10, "max_time": None}
    assert not run_finished(str(tmp_path), budget)
    mark_finished(str(tmp_path), budget, str(ckpt), 10)
    assert run_finished(str(tmp_path), budget) and not run_finished(str(tmp_path), {**budget, "max_steps": 20})

    out = tmp_path / "eval"
    out.mkdir()
    assert not eval_fresh(str(out), str(ckpt))
    (out / "metrics.json").write_text(json.dumps({"meta": {"ckpt": str(ckpt)}}))
    assert eval_fresh(str(out), str(ckpt)) and not eval_fresh(str(out), str(tmp_path / "other.ckpt"))
    later = os.path.getmtime(out / "metrics.json") + 10
    os.utime(ckpt, (later, later))  # the checkpoint was rewritten after the evaluation
    assert not eval_fresh(str(out), str(ckpt))
