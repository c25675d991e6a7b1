"""The std calibrations shipped with ``Predictor.from_arm``: fitted on simulated robots nothing was trained on.

    python benchmarks/arm_calibration.py --arm panda --robots 256 --test-robots 128
    python benchmarks/arm_calibration.py --arm panda --recipe realistic --robots 128 --test-robots 64

The untrained hybrid of a catalogue arm (:mod:`robomorph.inference.catalogue`) predicts what a
trained command-formulation hybrid predicts in its default mode; its std is the spread over the
robots the context allows, which is not calibrated. This script generates ``--robots`` randomized
arms of the shipped recipe ``--recipe`` (default ``multisine``, the generator's defaults) with seed
``--seed`` (not the seeds of the docs' or the demo's stores: 0 and 1), fits a ``power`` calibration
(:mod:`robomorph.inference.calibration`) of the windows that open their trajectory (context 200,
horizon 800, the training window of ``train_cpu.yaml``) and one of windows at random offsets
(horizon 600), then scores both on ``--test-robots`` other robots (seed ``--seed`` + 1): ±1σ / ±2σ
coverage of the joints before and after, at the first step, 0.25 s, 1 s, 5 s and the end. The
hybrid runs with from_arm's default settings, or those of ``--settings`` (a
:attr:`~robomorph.inference.settings.HybridSettings.key`); the calibrations are keyed by the switches
in effect, as a trained model keeps its own. It writes ``robomorph/inference/arm_calibrations/
<arm>-<recipe>.json`` (read offline by ``Predictor.from_arm``, which takes the file whose scope is
its own; the command, commit, date, machine, stores' seeds and the held-out coverage recorded in it)
and prints the coverage table. ``--offsets start`` fits the first kind alone (a hybrid then applies it to
both). ``--work DIR`` keeps the stores and the windows' scores (truths, means and raw stds, with each
window's trajectory row and start, ``<arm>-<recipe>_<seed>_<offset>.npz``) there, for studying the
coverage offline: a rerun takes a complete store and the scores of the same windows and settings instead
of generating and scoring them again (the realistic recipe's 192 robots cost an hour of two busy cores).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from contextlib import nullcontext

import numpy as np
from common import REPO, print_provenance

from robomorph.core.atomic import write_json
from robomorph.core.results import markdown_table, provenance
from robomorph.data.generation import generate
from robomorph.evaluation.calibrating import moving_windows
from robomorph.evaluation.scoring import Predictions, score_windows
from robomorph.evaluation.windows import load_window
from robomorph.inference import catalogue
from robomorph.inference.calibration import SPREAD_SWITCHES, fit
from robomorph.inference.hybrid_std import drawn_points
from robomorph.inference.predictor import Predictor
from robomorph.inference.settings import HybridSettings
from robomorph.reproduction.skip import ensure_store
from robomorph.sim.recipe import load_recipe

CONTEXT, HORIZON, MOVING_HORIZON = 200, 800, 600
STEPS = "1,0.25s,1s,5s,10s"  # 10 s: the end of the random-offset windows (600 steps)


def _store(folder: str, arm: str, recipe: str, robots: int, seed: int) -> str:
    path = os.path.join(folder, f"{arm}-{os.path.splitext(os.path.basename(recipe))[0]}_{seed}.zarr")
    ensure_store(load_recipe(recipe, {"robot": arm, "robots": robots, "seed": seed}), path)  # a complete one is kept
    return path


def _windows(pred: Predictor, store: str, offset: str):
    """The windows of ``offset`` and the store rows they come from."""
    horizon = HORIZON if offset == "start" else MOVING_HORIZON
    w = load_window(store, CONTEXT, horizon, None, pred.data_info, pred.n_u, pred.n_y, offset, 0, pred.inputs)
    rows = np.arange(len(w.u))
    return (w, rows) if offset == "start" else (moving_windows(w, offset), rows[w.starts > 0])


def _coverage(scores) -> dict:
    """The joints' ±1σ / ±2σ coverage at the reported steps (the goals are stated for the joints)."""
    cal = scores.result["horizons"]["calibration"]["joints"]
    return {"steps": scores.result["horizons"]["steps"], "1sigma": cal["1sigma"], "2sigma": cal["2sigma"]}


def _scores(pred: Predictor, store: str, offset: str):
    """The windows of ``offset`` in ``store`` scored by ``pred``: the scores kept beside the store for the same
    windows and settings where there are (``--work``), else scored and kept there."""
    w, rows = _windows(pred, store, offset)
    kept, key = f"{os.path.splitext(store)[0]}_{offset}.npz", pred.settings_in_effect.key
    if os.path.isfile(kept):
        k = np.load(kept)
        if (str(k["settings"]) == key and np.array_equal(k["rows"], rows) and np.array_equal(k["starts"], w.starts)
                and np.array_equal(k["y"], w.split()[3])):
            return w, rows, score_windows(Predictions(k["mean"], k["std"]), w, (), STEPS)
    scores = score_windows(pred, w, (), STEPS, batch_size=64)
    np.savez_compressed(kept, y=scores.y, mean=scores.preds["model"], std=scores.std, rows=rows, starts=w.starts,
                        settings=key)
    return w, rows, scores


def _predictor(arm: str, recipe: str, settings: str | None) -> Predictor:
    pred = Predictor.from_arm(arm, recipe, calibrated=False)
    return pred.configure(HybridSettings.from_key(settings, pred.settings)) if settings else pred


def run(arm: str, recipe: str, robots: int, test_robots: int, seed: int, out: str, settings: str | None = None,
        work: str | None = None, offsets: tuple[str, ...] = ("start", "random")) -> dict:
    pred = _predictor(arm, recipe, settings)
    used = pred.settings_in_effect
    entries, rows = {}, []
    if work:
        os.makedirs(work, exist_ok=True)
    with nullcontext(work) if work else tempfile.TemporaryDirectory(prefix="arm_calibration-") as tmp:
        fit_store, test_store = _store(tmp, arm, recipe, robots, seed), _store(tmp, arm, recipe, test_robots, seed + 1)
        for offset in offsets:
            w, _, raw = _scores(pred, fit_store, offset)
            # As robomorph calibrate records a hybrid's (its mode and the switches in effect), so the calibration is
            # keyed as a trained model's would be; "data" says what it was fitted on.
            source = {"data": [f"{robots} simulated {arm} robots ({recipe}, seed {seed})"],
                      "arm": arm, "recipe": recipe, "inputs": pred.inputs, "settings": used.key,
                      "robots": robots, "seed": seed, "n": int(len(w.u)), "context_len": CONTEXT,
                      "horizon": w.horizon, "offset": offset, "split": "whole", "physics_mode": used.mode,
                      **{name: bool(getattr(used, name)) for _, name in SPREAD_SWITCHES}}
            cal = fit(raw.y, raw.preds["model"], raw.std, "power", source=source, end=True, points=drawn_points(pred))
            tw, _, before = _scores(pred, test_store, offset)
            after = score_windows(Predictions(before.preds["model"], cal.scaled(before.std)), tw, (), STEPS)
            held_out = {"robots": test_robots, "seed": seed + 1, "n": int(len(tw.u)),
                        "before": _coverage(before), "after": _coverage(after)}
            cal.source["held_out"] = held_out
            entries[offset] = cal.to_dict()
            for when in ("before", "after"):
                c = held_out[when]
                rows.append(["from the start" if offset == "start" else "from random offsets", when,
                             *(f"{100 * a:.0f} / {100 * b:.0f}" for a, b in zip(c["1sigma"], c["2sigma"]))])
                steps = c["steps"]
    # scope: what a Predictor.from_arm must share with these robots for the calibration to apply.
    doc = {"arm": arm, "recipe": recipe, "scope": catalogue.calibration_scope(pred.data_info),
           "provenance": provenance(), "calibrations": entries}
    write_json(out, doc)
    print(f"joint ±1σ / ±2σ coverage [%] on {test_robots} held-out {arm} robots of {recipe} "
          f"({used.calibration_key}; ideal 68 / 95):")
    print(markdown_table(["windows", "std", *(f"step {s}" for s in steps)], rows))
    print(f"wrote {os.path.relpath(out, REPO)}")
    return doc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--arm", default="panda")
    p.add_argument("--recipe", default=catalogue.CALIBRATION_RECIPE,
                   help="a shipped recipe (datamodules/<name>.yaml) the robots are generated with")
    p.add_argument("--robots", type=int, default=256, help="robots the calibration is fitted on")
    p.add_argument("--test-robots", type=int, default=128, help="other robots it is scored on")
    p.add_argument("--seed", type=int, default=55)
    p.add_argument("--settings", help="the hybrid's settings as a key (e.g. regression+obs+springs+debias+coulomb"
                                      "+payload+denoise); default from_arm's")
    p.add_argument("--offsets", default="start,random", help="the kinds of windows fitted: start, random or both")
    p.add_argument("--work", help="a folder keeping the stores and the windows' scores (a rerun reuses them); "
                                  "default a temporary one")
    p.add_argument("--out", help="default: robomorph/inference/arm_calibrations/<arm>-<recipe>.json")
    args = p.parse_args(argv)
    print_provenance()
    run(args.arm, args.recipe, args.robots, args.test_robots, args.seed,
        args.out or catalogue.calibration_path(args.arm, args.recipe), args.settings, args.work,
        tuple(o for o in args.offsets.split(",") if o))
    return 0


if __name__ == "__main__":
    sys.exit(main())
