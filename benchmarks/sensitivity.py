"""Sensitivity tables: what each realism term costs every predictor, on the same held-out robots.

For each condition a small held-out store of Panda robots is generated (the ``multisine`` recipe, one
seed, so every condition holds the same robots, signals and initial poses: the realism draws come from
streams of their own, :mod:`robomorph.sim.realism`) and scored, windows from the trajectory start, in the
command formulation (``u_cmd``), through :func:`robomorph.evaluation.scoring.score_windows`:

- ``hybrid``: ``Predictor.from_arm`` (no training) with the store's own recipe, its default settings
  (regression, observer, springs, debiasing where in effect), and each ``--variant`` (a
  :class:`robomorph.inference.settings.HybridSettings` change, e.g. ``offsets=True``);
- ``identified_physics`` (``--identified``; slow), ``nominal_physics`` (the catalogue robot), ``hold``,
  ``constant_velocity``.

The conditions (:data:`CONDITIONS`): the clean recipe; encoder noise of 1e-5 and 1e-4 rad on the
context's joint angles only (added here to the clean store's contexts, the EE pose recomputed from the
noisy joints, so the horizon is scored against the true motion); the controller compensating gravity
with the catalogue model; an unconfigured payload (under the feedback controller); Coulomb + viscous + Stribeck friction beside
MuJoCo's; robots drawn outside the identification box; feedback-controlled excitation; and the whole
``realistic`` recipe. Joint RMS error [mrad] at steps 1, 15, 60, 300 and 800 (1/60 s to 13.3 s).

    python benchmarks/sensitivity.py --n 16 --identified --variant offsets=True \\
        --md results/benchmarks/sensitivity.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import yaml
from common import check_outputs, print_provenance

from robomorph.core.config import yaml_value
from robomorph.core.errors import run_command
from robomorph.core.results import markdown_table, provenance, write_markdown, write_rows
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.sources import predict
from robomorph.evaluation.windows import load_window, start_joints

STEPS = (1, 15, 60, 300, 800)
SEED = 5454  # the held-out robots: no store of the docs or the demo is drawn from it
CONTEXT, HORIZON = 200, 800
_FRICTION = {"coulomb": [0.15, 0.65], "viscous": [0.0, 0.2], "stribeck_ratio": [1.0, 1.5],
             "stribeck_velocity": [0.05, 0.2], "asymmetry": 0.2, "smoothing_velocity": 0.1}
# name -> (recipe, recipe overrides, encoder noise std on the context's joints [rad], store name)
CONDITIONS = {
    "clean": ("multisine", {}, 0.0, "clean"),
    "encoder 1e-5 rad": ("multisine", {}, 1e-5, "clean"),
    "encoder 1e-4 rad": ("multisine", {}, 1e-4, "clean"),
    "nominal gravity compensation": ("multisine", {"gravity_compensation": "nominal_model"}, 0.0, "nominal"),
    # Open loop, an arm with an unknown payload sags into a contact within seconds (12 of 256 attempts kept):
    # the payload is carried under the feedback controller, against the feedback condition without it.
    "unconfigured payload (under feedback)": ("multisine", {"gravity_compensation": "nominal_model", "realism": {
        "payload": {"mass": [0.2, 1.0], "com": 0.05, "configured": 0.0}, "feedback": {"enabled": True}}},
        0.0, "payload"),
    "Coulomb+viscous+Stribeck friction": ("multisine", {"realism": {"friction": _FRICTION}}, 0.0, "friction"),
    "out of the box (widen 1.5)": ("multisine", {"realism": {"widen": 1.5}}, 0.0, "widen"),
    "feedback-controlled excitation": ("multisine", {"realism": {"feedback": {"enabled": True}}}, 0.0, "feedback"),
    "realistic recipe": ("realistic", {}, 0.0, "realistic"),
}


def recipe_of(name: str, overrides: dict, n: int):
    """The held-out recipe of a condition: ``n`` robots of :data:`SEED`, a window's length each."""
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    return load_recipe(name, {**overrides, "robots": n, "seed": SEED, "steps": CONTEXT + HORIZON,
                              "chunk": min(n, 64)})


def store(folder: str, key: str, recipe) -> str:
    """Generates (or finds) the condition's store."""
    from robomorph.data.generation import generate  # noqa: PLC0415

    path = os.path.join(folder, f"{key}.zarr")
    t0 = time.perf_counter()
    generate(recipe, path, progress=False)
    print(f"store {key}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return path


def noisy_context(w, std: float, seed: int = 0):
    """The window with Gaussian noise of ``std`` rad on its context's joint angles (the horizon untouched),
    the context's EE pose recomputed from the noisy joints as a real arm computes it from its encoders."""
    from dataclasses import replace  # noqa: PLC0415

    from robomorph.identification.identify import lean_model  # noqa: PLC0415
    from robomorph.sim.filters import continuous_quaternion  # noqa: PLC0415
    from robomorph.sim.kinematics import SiteKinematics  # noqa: PLC0415

    if std <= 0:
        return w
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(7,)))
    y = w.y.astype(np.float64).copy()
    c, j = w.context_len, slice(7, 14)
    y[:, :c, j] += rng.normal(0.0, std, y[:, :c, j].shape)
    pos, quat = SiteKinematics(lean_model(8, w.dt, False))(y[:, :c, j])
    quat = continuous_quaternion(quat)[..., [1, 2, 3, 0]]
    flip = np.einsum("ntk,ntk->nt", quat, y[:, :c, 3:7]) < 0  # the log's sign convention
    quat[flip] *= -1.0
    y[:, :c, :3], y[:, :c, 3:7] = pos, quat
    return replace(w, y=y.astype(w.y.dtype))


def hybrid_predictor(w, variant: dict):
    """``Predictor.from_arm`` of the store's own recipe (physics step, gravity compensation, ranges)."""
    import tempfile  # noqa: PLC0415

    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    config = dict(w.attrs["config"])
    with tempfile.NamedTemporaryFile("w", suffix=".yaml", delete=False) as f:
        yaml.safe_dump(config, f)
    try:
        pred = Predictor.from_arm("panda", recipe=f.name, calibrated=False)
    finally:
        os.remove(f.name)
    return pred.configure(**variant) if variant else pred


def hybrid_scores(w, variant: dict) -> tuple[np.ndarray, float]:
    """(N, H, n_y) the hybrid's predictions on ``w`` and its cost per window [s]."""
    pred = hybrid_predictor(w, variant)
    u_ctx, y_ctx, u_q, _ = w.split()
    t0 = time.perf_counter()
    out = predict(pred, u_ctx, y_ctx, u_q, 64, desc="hybrid", at_rest=w.starts == 0, anchor=start_joints(w))
    return out, (time.perf_counter() - t0) / len(u_ctx)


def parse_variant(text: str) -> tuple[str, dict]:
    """``name=value[,name=value]`` (values read as YAML) -> (label, settings changes)."""
    changes = {}
    for item in text.split(","):
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"error: --variant takes NAME=VALUE[,NAME=VALUE], got {text!r}")
        changes[key.strip()] = yaml_value(value, f"--variant {key.strip()}")
    return "hybrid " + text, changes


def score_condition(name: str, spec: tuple, folder: str, args) -> list[dict]:
    recipe_name, overrides, noise, key = spec
    path = store(folder, key, recipe_of(recipe_name, overrides, args.n))
    w = load_window(path, CONTEXT, HORIZON, args.n, None, 7, 14, "start", 0, "command")
    w = noisy_context(w, noise)
    others, seconds = {}, {}
    hybrids = [] if args.no_hybrid else [("hybrid", {})] + [parse_variant(v) for v in args.variant]
    for label, variant in hybrids:
        others[label], seconds[label] = hybrid_scores(w, variant)
    baselines = ["hold", "constant_velocity", "nominal_physics"] + (["identified_physics"] if args.identified else [])
    t0 = time.perf_counter()
    scores = score_windows(None, w, baselines=baselines, steps=list(STEPS), others=others)
    base_seconds = time.perf_counter() - t0
    notes = scores.result["meta"]["baseline_notes"]
    rows = []
    for source in scores.preds:
        row = {"condition": name, "source": source}
        row.update({f"step{k}": round(scores.at(source, "joints", k), 4) for k in STEPS})
        s = seconds.get(source, notes.get(source, {}).get("seconds_per_window"))
        row["s_per_window"] = round(float(s), 4) if s is not None else ""
        rows.append(row)
        print(row, file=sys.stderr, flush=True)
    print(f"{name}: baselines {base_seconds:.1f} s", file=sys.stderr, flush=True)
    return rows


def render(rows: list[dict], args) -> str:
    parts = [f"# Sensitivity: what each realism term costs every predictor\n\n{args.n} held-out Panda robots "
             f"(seed {SEED}, the same robots, signals and initial poses in every condition), windows from the "
             f"trajectory start, context {CONTEXT}, horizon {HORIZON} at 60 Hz, command formulation (`u_cmd`). "
             "Joint RMS error [mrad] at steps 1 / 15 / 60 / 300 / 800 (1/60 s, 0.25 s, 1 s, 5 s, 13.3 s); the "
             "hybrid is `Predictor.from_arm` with the store's recipe (no training), its cost per window on this "
             "machine. Encoder noise is on the context's joints only (the EE pose recomputed from them); the "
             "horizon is scored against the true motion. Conditions: `benchmarks/sensitivity.py`'s CONDITIONS."]
    for cond in dict.fromkeys(r["condition"] for r in rows):
        table = markdown_table(["source", *(f"step {k}" for k in STEPS), "s / window"],
                               [[r["source"], *(r[f"step{k}"] for k in STEPS), r["s_per_window"]]
                                for r in rows if r["condition"] == cond], floatfmt=".3g")
        parts.append(f"## {cond}\n\n{table}")
    return "\n\n".join(parts)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--n", type=int, default=16, help="held-out robots per condition")
    p.add_argument("--work", default="data/sensitivity", help="where the conditions' stores are written")
    p.add_argument("--only", help="comma list of condition names (default: all)")
    p.add_argument("--identified", action="store_true", help="score identified_physics too (seconds per window)")
    p.add_argument("--variant", action="append", default=[], metavar="NAME=VALUE[,NAME=VALUE]",
                   help="a hybrid with these settings changed, scored beside the default (repeatable)")
    p.add_argument("--no-hybrid", action="store_true", help="score the baselines alone (with --identified: its table)")
    p.add_argument("--md", help="write the tables (with provenance) here, and the rows beside it as CSV")
    args = p.parse_args(argv)
    check_outputs(md=args.md, work=args.work)
    prov = provenance()
    print_provenance()
    only = [c.strip() for c in args.only.split(",")] if args.only else list(CONDITIONS)
    unknown = [c for c in only if c not in CONDITIONS]
    if unknown:
        raise SystemExit(f"error: unknown conditions {unknown}; choose from {list(CONDITIONS)}")
    n = f"n{args.n}"
    folder = os.path.join(args.work, n)
    rows = []
    for name in only:
        rows += score_condition(name, CONDITIONS[name], folder, args)
        if args.md:  # what is done so far, in case a long run is stopped
            write_rows(os.path.splitext(args.md)[0] + ".csv", rows, prov)
            write_markdown(args.md, render(rows, args), prov)
    print(render(rows, args))
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
