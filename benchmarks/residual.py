"""The learned residual against the hybrid alone, on held-out robots of the ``realistic`` recipe.

One held-out store of Panda robots (the ``realistic`` recipe, seed :data:`SEED`, which no training store
may share: a model whose priors came from a store of this seed is refused), windows from each
trajectory's start (or from step ``--offset``, mid-motion), context :data:`CONTEXT` and horizon
``--horizon`` (default :data:`HORIZON`), the command formulation. On the same windows:

- ``hold``, ``constant_velocity``, ``nominal_physics`` (the catalogue robot);
- ``hybrid``: ``Predictor.from_arm`` with the store's recipe and the settings the models' priors were
  made with (``robomorph priors``, by default payload, coulomb and denoise on);
- each ``--model NAME=CKPT``: a residual model (``robomorph fit`` on prior stores), given that same
  hybrid prediction as its prior (``Predictor.simulate(..., prior=...)``), so the two differ only by
  the learned correction.

Joint RMS error [mrad] at steps 1, 15, 60 and 300 (and 800 when the horizon reaches it), and for each
residual model the share of windows whose joint error at the last of them is below the hybrid's.

    python benchmarks/residual.py --model residual=results/runs/residual-cpu/checkpoints/best.ckpt \\
        --n 64 --md results/benchmarks/residual.md
    python benchmarks/residual.py --model ... --n 64 --offset 300 --md results/benchmarks/residual_offset300.md
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
from common import check_outputs, print_provenance

from robomorph.core.errors import RoboMorphError, run_command
from robomorph.core.results import markdown_table, provenance, write_markdown
from robomorph.evaluation.priors import PriorRequest, write_priors
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.windows import load_window
from robomorph.inference.predictor import Predictor

SEED = 5455  # the held-out robots: no training store may be drawn from it
CONTEXT, HORIZON = 200, 300
STEPS = (1, 15, 60, 300, 800)


def held_out_store(folder: str, n: int, horizon: int, offset: int = 0) -> str:
    """Generates (or finds, or resumes) the held-out store: ``n`` realistic Panda robots of :data:`SEED`, long enough
    for a window from step ``offset``."""
    from robomorph.data.generation import generate  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    steps = offset + CONTEXT + horizon
    path = os.path.join(folder, f"heldout_n{n}_t{steps}.zarr")
    recipe = load_recipe("realistic", {"robots": n, "seed": SEED, "steps": steps, "chunk": min(n, 64)})
    t0 = time.perf_counter()
    generate(recipe, path, progress=False)
    print(f"held-out store {path}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return path


def load_models(specs: list[str]) -> dict[str, Predictor]:
    """``NAME=CKPT`` -> residual Predictors, refused unless each is a residual model of robots other than
    the held-out ones and all share the prior's settings."""
    models = {}
    for spec in specs:
        name, sep, path = spec.partition("=")
        if not sep or not name or not path:
            raise RoboMorphError(f"--model takes NAME=CKPT, got {spec!r}")
        pred = Predictor.from_checkpoint(path, device="cpu")
        if pred.residual is None:
            raise RoboMorphError(f"--model {spec}: not a residual model (train one with robomorph fit on a prior store)")
        if pred.residual.get("source_seed") == SEED:
            raise RoboMorphError(f"--model {spec}: its priors came from robots of seed {SEED}, the held-out seed")
        models[name] = pred
    keys = {name: p.residual.get("settings") for name, p in models.items()}
    if len(set(keys.values())) > 1:
        raise RoboMorphError(f"the models' priors were made with different hybrid settings: {keys}")
    return models


def run(args) -> str:
    models = load_models(args.model)
    # The first model's hybrid settings (those that change a prediction: the threads are this machine's).
    settings = {k: v for k, v in (next(iter(models.values())).residual.get("fields") or {}).items()
                if k != "workers"} if models else None
    path = held_out_store(args.work, args.n, args.horizon, args.offset)
    prior_path = os.path.splitext(path)[0] + (f"_o{args.offset}" if args.offset else "") + "_priors.zarr"
    req = PriorRequest(path, prior_path, CONTEXT, args.horizon, (args.offset,), args.n, overwrite=False,
                       **({"settings": tuple(settings.items())} if settings is not None else {}))
    t0 = time.perf_counter()
    record = write_priors(req)  # resumes, or finds it complete
    print(f"hybrid priors: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    from robomorph.data.store import open_store  # noqa: PLC0415

    prior = open_store(prior_path).read("prior").astype(np.float64)
    w = load_window(path, CONTEXT, args.horizon, args.n, None, 7, 14, args.offset or "start", 0, "command")
    u_ctx, y_ctx, u_q, _ = w.split()
    others = {"hybrid": prior}
    for name, pred in models.items():
        t0 = time.perf_counter()
        others[name] = np.concatenate([pred.simulate(u_ctx[s:s + 64], y_ctx[s:s + 64], u_q[s:s + 64],
                                                     prior=prior[s:s + 64]) for s in range(0, len(u_ctx), 64)])
        print(f"{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    steps = [k for k in STEPS if k <= args.horizon]
    scores = score_windows(None, w, baselines=["hold", "constant_velocity", "nominal_physics"], steps=steps,
                           others=others)
    last = steps[-1]
    rows = [[source, *(scores.at(source, "joints", k) for k in steps), _better(others, source, w, last)]
            for source in scores.preds]
    table = markdown_table(["source", *(f"step {k}" for k in steps), f"windows better than hybrid at step {last} [%]"],
                           rows, floatfmt=".3g")
    where = f"windows from step {args.offset} (mid-motion)" if args.offset else "windows from the trajectory start"
    described = ", ".join(f"`{name}` = `{os.path.relpath(p.partition('=')[2])}`" for name, p in
                          zip(models, args.model)) or "none"
    return (f"# The learned residual against the hybrid alone\n\n{args.n} held-out Panda robots of the `realistic` "
            f"recipe (seed {SEED}), {where}, context {CONTEXT}, horizon {args.horizon} at "
            f"60 Hz, command formulation (`u_cmd`). Joint RMS error [mrad] at steps {' / '.join(map(str, steps))}. "
            f"`hybrid`: `{record['settings']}` (no training); the residual models ({described}) correct that very "
            f"prediction.\n\n{table}")


def _better(others: dict, source: str, w, step: int):
    """The share of windows [%] whose joint RMS error at ``step`` is below the hybrid's (residual models only)."""
    if source not in others or source == "hybrid":
        return None
    joints = [w.y_names.index(f"q{i}") for i in range(7)]
    _, _, _, y_q = w.split()

    def err(pred):
        return np.sqrt(((pred[:, step - 1, joints] - y_q[:, step - 1, joints]) ** 2).mean(-1))

    return 100.0 * float((err(others[source]) < err(others["hybrid"])).mean())


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--model", action="append", default=[], metavar="NAME=CKPT", help="a residual model (repeatable)")
    p.add_argument("--n", type=int, default=24, help="held-out robots")
    p.add_argument("--horizon", type=int, default=HORIZON, help="query steps scored")
    p.add_argument("--offset", type=int, default=0, help="each window's first step (0: the trajectory start, at rest)")
    p.add_argument("--work", default="data/residual/bench", help="where the held-out store and its priors go")
    p.add_argument("--md", help="write the table (with provenance) here")
    args = p.parse_args(argv)
    check_outputs(md=args.md, work=args.work)
    prov = provenance()
    print_provenance()
    text = run(args)
    if args.md:
        write_markdown(args.md, text, prov)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
