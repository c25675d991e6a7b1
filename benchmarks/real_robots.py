"""Real robots are the judge: every predictor on the public logs of real arms, one table per robot.

The sources (:mod:`robomorph.data.public_logs`) are public repositories cloned into one folder,
``--data DIR``; nothing is downloaded here. Each robot's recordings are split by recording
(the source's rule: no test window comes from a recording that trained or identified
anything), ingested at the rate the source names (the log's own, or resampled through
``ingest``'s anti-aliasing filter) and cut into windows of ``context + horizon`` samples.

Scored on the same test windows, through :func:`robomorph.evaluation.scoring.score_windows`:

- ``hold``, ``constant_velocity``, ``constant_acceleration``: the kinematic bars;
- ``arx``: a linear ARX fitted on each window's own context; ``arx_train``: one fitted on the
  robot's training recordings;
- ``accel_arx``, ``accel_arx_train``: the same two in acceleration form (a double integrator
  whose acceleration is linear in the torque), which cannot drift from smooth motion;
- ``nominal_physics``: the catalogue arm (where the robot has an MJCF in the arms registry)
  driven by the logged torques from the end of the context;
- ``identified_physics`` (``--identified``): that arm with masses, damping, armature and
  friction fitted to each context;
- ``hybrid`` (where the arm is registered): ``Predictor.from_arm`` (no training) identifying the
  robot in each context by its regression solve and simulating it: ``hybrid (total)`` on the
  logged total torque, ``hybrid (nominal commands)`` on the command an arm that compensates its
  gravity with its catalogue model is sent (the logged torque less the catalogue's g(q));
- ``hybrid_train``, ``hybrid_train +offsets``, ``hybrid_train +offsets +residual`` (where the arm is registered): the
  hybrid identified once over the robot's training recordings, then its offsets adapted per context, then an
  acceleration-space residual learned on those recordings (``benchmarks/training_recordings.py``), with the goal
  "with the arm's training recordings" for each and what each term buys under the table; on every arm,
  ``constant_velocity +residual``: constant velocity corrected by the same residual, learned on the training
  recordings;
- ``stacked (kinematic)``, ``stacked (zero-shot)``, ``stacked (training recordings)`` (unless ``--no-stacked``):
  the context backtest's stacks of :mod:`robomorph.inference.stacking`, as ``benchmarks/stacking.py`` builds them,
  with each goal of issue 62 and its verdict under the table;
- any checkpoint given with ``--model NAME=CKPT`` (zero-shot, fine-tuned or trained from
  scratch: the name says which), where its channels and rate match the robot's store.

Reported: joint RMS error [mrad] at the first step, 0.25 s, 1 s and 5 s where the horizon
reaches them, and FIT [%] over the horizon (each joint over all windows, then the joints' mean). Under the industrial
robot's table, its benchmark by its own published readings ((a)-(d) of ``benchmarks/industrial_robot.py``) for hold,
constant velocity and the least-squares ARX; the models trained for that benchmark are in that script.

    python benchmarks/real_robots.py --data data/sources --md results/benchmarks/real_robots.md
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
from common import print_provenance

from robomorph.core.atomic import check_not_input, check_outside_stores, check_replaceable
from robomorph.core.errors import OutputExistsError, RoboMorphError, run_command
from robomorph.core.results import markdown_table, provenance, write_markdown
from robomorph.data import public_logs
from robomorph.data.store import open_store
from robomorph.evaluation.scoring import score_windows
from robomorph.evaluation.sources import predict
from robomorph.evaluation.windows import load_window

KINEMATIC = ("hold", "constant_velocity", "constant_acceleration")
TIMES = ((None, "step 1"), (0.25, "0.25 s"), (1.0, "1 s"), (5.0, "5 s"))


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--data", required=True, help="folder holding the sources' clones (docs/guide/real-robots.md)")
    p.add_argument("--robots", default=",".join(public_logs.SOURCES),
                   help=f"comma list from {', '.join(public_logs.SOURCES)} (default: all)")
    p.add_argument("--work", default="data/real", help="where the robots' stores are written (default: data/real)")
    p.add_argument("--windows", type=int, help="score only the first N test windows of each robot")
    p.add_argument("--identified", action="store_true", help="also fit identified_physics to each context (slow)")
    p.add_argument("--no-stacked", action="store_true",
                   help="leave out the context backtest's stacks and the goals' verdicts (benchmarks/stacking.py)")
    p.add_argument("--download-industrial", action="store_true",
                   help="have the official loader (pip install nonlinear-benchmarks) download the industrial robot "
                        "benchmark into DATA/nonlinear_benchmarks first, unless a clone of its copy is there")
    p.add_argument("--model", action="append", default=[], metavar="NAME=CKPT",
                   help="a checkpoint scored as NAME on every robot whose store it reads (repeatable)")
    p.add_argument("--hybrid", action="append", default=[], metavar="KEY",
                   help="also score both hybrids with these settings, named by their key (HybridSettings.key, e.g. "
                        "regression+obs+springs+debias+payload+coulomb+denoise; repeatable)")
    p.add_argument("--md", help="write the tables (with provenance) to this Markdown file")
    p.add_argument("--plots", help="write each robot's error growth (joint RMS against time, every predictor) as "
                   "PNG files into this folder (default with --md: the Markdown file's name as a folder beside it)")
    args = p.parse_args(argv)
    args.robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    for name in args.robots:
        public_logs.get(name)
    if args.windows is not None and args.windows < 1:
        p.error("--windows must be >= 1")
    models = {}
    for item in args.model:
        name, sep, path = item.partition("=")
        if not sep or not name or not path:
            p.error(f"--model takes NAME=CKPT, got {item!r}")
        models[name] = path
    args.model = models
    check_models(models)
    from robomorph.inference.settings import HybridSettings, SettingsError  # noqa: PLC0415

    for key in args.hybrid:
        try:
            HybridSettings.from_key(key)
        except SettingsError as exc:
            p.error(f"--hybrid: {exc}")
    if args.plots is None and args.md:
        args.plots = os.path.splitext(args.md)[0]
    return args


def report_steps(horizon: int, dt: float) -> list[tuple[int, str]]:
    """The (1-based step, label) pairs of :data:`TIMES` that the horizon reaches."""
    out = []
    for t, label in TIMES:
        k = 1 if t is None else int(round(t / dt))
        if t is not None and abs(k * dt - t) > 1e-6 * t:
            label = f"{k * dt:.3g} s"  # the rate has no sample at t: the nearest step, named by its time
        if 1 <= k <= horizon and k not in [s for s, _ in out]:
            out.append((k, label))
    return out


def joint_fit(result: dict, name: str, joints: list[str]) -> float:
    """FIT [%] of a source over the horizon, the joints' mean: each joint's windows taken together
    (approach 2), so a window where a joint barely moves does not swamp the figure."""
    res = result if name == "model" else result["baselines"][name]
    return float(np.mean([res["approach2"]["channels"][q]["fit"] for q in joints]))


def check_models(paths: dict[str, str]) -> None:
    """Refuses, before any store is written or any window scored, a ``--model`` that is missing or no checkpoint
    (it used to be found after the whole run, as a footnote, with exit code 0). Whether it reads a robot's store
    is that robot's question (:func:`_models`)."""
    from robomorph.inference.checkpoint import load_trained  # noqa: PLC0415

    for name, path in paths.items():
        try:
            load_trained(path)
        except RoboMorphError as exc:
            raise type(exc)(f"--model {name}={path}: {exc}") from None


def _models(paths: dict[str, str], store: str) -> tuple[dict, dict]:
    """The checkpoints that read ``store`` (loaded), and why each other one was skipped."""
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    loaded, skipped = {}, {}
    ds = open_store(store)
    for name, path in paths.items():
        try:
            pred = Predictor.from_checkpoint(path, device="cpu")
            info = pred.data_info
            # A model of several arms carries their union and records each arm's layout: it reads a store of one.
            names = [list(info["y_names"])] + [list(lay["y_names"]) for lay in info.get("layouts", [])]
            if list(ds.y_names) not in names or abs(float(info.get("dt", ds.dt)) - ds.dt) > 1e-6 * ds.dt:
                skipped[name] = "trained on other channels or another rate"
                continue
            loaded[name] = pred
        except RoboMorphError as exc:
            skipped[name] = str(exc)
    return loaded, skipped


def hybrid_predictions(arm: str, w, keys: list[str] = ()) -> dict[str, np.ndarray]:
    """The hybrid with no training on the windows, as a real arm's torques can be given to it:
    the total torque, and the command of an arm compensating its gravity with the catalogue model;
    each with its default settings, then with each of ``keys`` (:meth:`HybridSettings.from_key`)."""
    from robomorph.inference.settings import HybridSettings  # noqa: PLC0415
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415
    from robomorph.sim import arms  # noqa: PLC0415
    from robomorph.sim.episode import NominalGravity  # noqa: PLC0415
    from robomorph.sim.recipe import load_recipe  # noqa: PLC0415

    u_ctx, y_ctx, u_q, _ = w.split()
    n = arms.get(arm).n_joint
    out = {}
    total = Predictor.from_arm(arm, "multisine", inputs="total", dt=w.dt, gravity_compensation="none")
    out["hybrid (total)"] = total.simulate(u_ctx, y_ctx, u_q)
    default_total = total.settings
    for key in keys:
        total.configure(HybridSettings.from_key(key, base=default_total))
        out[f"hybrid (total) {key}"] = total.simulate(u_ctx, y_ctx, u_q)
    gravity = NominalGravity(load_recipe("multisine", {"robot": arm, "dt": w.dt}))
    cmd = w.u - np.stack([[gravity(q) for q in y[:, 7:7 + n]] for y in w.y.astype(np.float64)])
    c = w.context_len
    nominal = Predictor.from_arm(arm, "multisine", dt=w.dt, gravity_compensation="nominal_model")
    out["hybrid (nominal commands)"] = nominal.simulate(cmd[:, :c], y_ctx, cmd[:, c:])
    default_nominal = nominal.settings
    for key in keys:
        nominal.configure(HybridSettings.from_key(key, base=default_nominal))
        out[f"hybrid (nominal commands) {key}"] = nominal.simulate(cmd[:, :c], y_ctx, cmd[:, c:])
    return out


def score_robot(source: public_logs.PublicLog, args) -> dict:
    """Scores every predictor on one robot's test windows; returns its table's rows and notes."""
    stores = public_logs.write_stores(source, args.data, os.path.join(args.work, source.name), overwrite=True)
    if not {"train", "test"} <= set(stores):
        raise public_logs.PublicLogError(f"{source.name}: no recording of the train or the test split is long enough "
                                         f"for one window of {source.context + source.horizon} samples; is the clone "
                                         "complete?")
    test, train = open_store(stores["test"]), open_store(stores["train"])
    w = load_window(stores["test"], source.context, source.horizon, args.windows, None,
                    len(test.u_names), len(test.y_names))
    baselines = list(KINEMATIC) + ["arx", "arx_train", "accel_arx", "accel_arx_train"]
    if source.arm:
        baselines.append("nominal_physics")
        if args.identified:
            baselines.append("identified_physics")
    models, skipped_models = _models(args.model, stores["test"])
    u_ctx, y_ctx, u_q, _ = w.split()
    for name in list(models):  # a checkpoint that refuses these windows is named with its reason, not fatal
        try:
            models[name] = predict(models[name], u_ctx, y_ctx, u_q, 64, desc=name)
        except RoboMorphError as exc:
            skipped_models[name] = str(exc)
            del models[name]
    fitted = None  # the hybrid identified over the training recordings (benchmarks/training_recordings.py)
    if source.arm:
        models.update(hybrid_predictions(source.arm, w, args.hybrid))
        from training_recordings import recordings_predictions  # noqa: PLC0415

        trained, fitted = recordings_predictions(source.arm, w, stores["train"])
        models.update(trained)
    from training_recordings import kinematic_predictions  # noqa: PLC0415

    trained, kinematic = kinematic_predictions(w, stores["train"])  # every arm: constant velocity + the residual
    models.update(trained)
    verdicts = []
    if not args.no_stacked:  # the same stacks and verdicts as benchmarks/stacking.py, on these windows
        from stacking import stacked_predictions, summarize  # noqa: PLC0415

        stacked, stds = stacked_predictions(source.arm, w, stores["train"])
        models.update({name: stacked[name] for name in stds})
        verdicts = summarize(source, w, stacked, stds)["verdicts"]

    def train_blocks():
        for s in range(0, train.n, 256):
            rows = slice(s, s + 256)
            yield train.read("u", rows), train.read("y", rows)

    steps = report_steps(w.horizon, w.dt)
    scores = score_windows(None, w, baselines=baselines, steps=[k for k, _ in steps], others=models,
                           train_blocks=train_blocks)
    joints = [n for n in w.y_names if n.startswith("q")]
    from training_recordings import recordings_verdicts  # noqa: PLC0415

    verdicts = verdicts + recordings_verdicts(steps, lambda n, k: scores.at(n, "joints", k),
                                              lambda n: joint_fit(scores.result, n, joints), fitted, kinematic)
    if args.plots:
        from robomorph.evaluation.plots import plot_error_growth  # noqa: PLC0415

        os.makedirs(args.plots, exist_ok=True)
        cols = [w.y_names.index(q) for q in joints]
        plot_error_growth(os.path.join(args.plots, f"{source.name}.png"), scores.y[..., cols],
                          {k: v[..., cols] for k, v in scores.preds.items()}, w.dt, joints,
                          [k for k, _ in steps], ["rad"] * len(joints))
    rows = []
    for name in scores.preds:
        rows.append([name] + [scores.at(name, "joints", k) for k, _ in steps]
                    + [joint_fit(scores.result, name, joints)])
    recs = source.recordings(args.data)
    return {"source": source, "steps": steps, "rows": rows, "windows": len(w.u), "dt": w.dt,
            "train_windows": train.n, "skipped": {**scores.result["skipped_baselines"], **skipped_models},
            "notes": scores.result["meta"].get("baseline_notes", {}),
            "recordings": {sp: sum(r.split == sp for r in recs) for sp in public_logs.SPLITS},
            "readings": industrial_readings(args.data) if source.name == "industrial_robot" else None,
            "verdicts": verdicts}


def industrial_readings(data: str) -> list:
    """The industrial robot benchmark's own readings (``benchmarks/industrial_robot.py``'s columns (a)-(d))
    of the predictors that train nothing or in a second (hold, constant velocity, least-squares ARX), on the
    benchmark's file under ``data``; (d) by this project's arithmetic (tested against identibench's)."""
    from industrial_robot import build  # noqa: PLC0415

    from robomorph.data import industrial  # noqa: PLC0415
    from robomorph.evaluation import benchmark_readings as br  # noqa: PLC0415

    bench = industrial.load(data)
    rows = []
    for name in ("hold", "constant_velocity", "arx_ls"):
        pred = build(name, bench, None)[0]
        r = br.readings(pred, bench.test, 1, identibench=False)
        rows.append([name] + [r[k] for k in br.READINGS])
    return rows


def render(res: dict) -> str:
    s = res["source"]
    rate = f"resampled to {1 / res['dt']:.6g} Hz" if s.hz else f"at its own {1 / res['dt']:.6g} Hz"
    head = (f"## {s.robot}\n\n{res['windows']} test windows of {s.context} + {s.horizon} samples, {rate}; "
            f"recordings train / val / test: {res['recordings']['train']} / {res['recordings']['val']} / "
            f"{res['recordings']['test']} ({s.split_rule}); torque: {s.torque}; source: `{s.clone}` "
            f"({s.licence}).\n\n")
    table = markdown_table(["joint RMS [mrad]"] + [label for _, label in res["steps"]] + ["FIT [%]"],
                           res["rows"], floatfmt=".3g")
    extra = ""
    if res["skipped"]:
        extra += "\n\nNot scored: " + "; ".join(f"{k}: {v}" for k, v in res["skipped"].items()) + "."
    diverged = {k: v["diverged_held"] for k, v in res["notes"].items() if isinstance(v, dict) and v.get("diverged_held")}
    if diverged:
        extra += "\n\nARX simulations that diverged and were held instead: " + ", ".join(
            f"{k} {v} of {res['windows']}" for k, v in diverged.items()) + "."
    if res.get("readings"):
        # The benchmark's own readings replace an NRMSE of these windows printed beside figures of another reading.
        extra += ("\n\nThe benchmark by its published readings, free-run over its test trajectories from their first "
                  "sample: (a) the whole test as one sequence, the paper's Eq. 23; (b) each trajectory from rest, "
                  "Eq. 23; (c) range-normalised per trajectory (the authors' code); (d) identibench's specs, RMSE "
                  "[deg]. Here the predictors that train nothing or in a second; the models trained for the benchmark and an "
                  "ensemble, beside the goals (c) <= 0.10 and (a) <= 0.45, are in `benchmarks/industrial_robot.py` "
                  "(results/benchmarks/industrial_robot.md).\n\n"
                  + markdown_table(["predictor", "(a) whole test, Eq. 23", "(b) per trajectory, Eq. 23",
                                    "(c) range-normalised", "(d) simulation [deg]", "(d) prediction [deg]"],
                                   res["readings"], floatfmt=".4g"))
    if res.get("verdicts"):
        extra += ("\n\nIssue 62's goals (the stacks' rows, their ratios to the best kinematic bar and the std's coverage "
                  "in `benchmarks/stacking.py`; the training recordings' rows, `benchmarks/training_recordings.py`):\n\n"
                  + "\n".join(f"- {v}" for v in res["verdicts"]))
    return head + table + extra


def check_outputs(args) -> None:
    """Refuses, before any store is written or any window scored, outputs that would destroy
    something: ``--md`` over anything but an earlier result file (a checkpoint, notes) or inside
    a store, ``--work`` or ``--plots`` that is or lies inside a store, or a ``--work`` that is
    (or holds) the sources' folder."""
    if args.md:
        check_replaceable(args.md, "markdown", "--md")
        check_not_input(args.md, [args.data, *args.model.values()], "--md")
    for flag, folder in (("--work", args.work), ("--plots", args.plots)):
        if folder:
            check_outside_stores(folder, flag, may_be_store=False)
            check_not_input(folder, [args.data, *args.model.values()], flag)
            if os.path.exists(folder) and not os.path.isdir(folder):
                raise OutputExistsError(f"{flag} {folder} is a file, not a folder; choose another {flag}")


def main(argv=None) -> int:
    args = parse_args(argv)
    check_outputs(args)
    print_provenance()
    if args.download_industrial and "industrial_robot" in args.robots and not os.path.isdir(
            os.path.join(args.data, public_logs.SOURCES["industrial_robot"].folders[0])):
        print(f"downloaded {public_logs.download_industrial(args.data)}", flush=True)
    parts = []
    for name in args.robots:
        print(f"{name}: ingesting and scoring ...", file=sys.stderr, flush=True)
        text = render(score_robot(public_logs.get(name), args))
        print("\n" + text, flush=True)
        parts.append(text)
    if args.md:
        write_markdown(args.md, "# Real robots: every predictor on public logs of real arms\n\n" + "\n\n".join(parts),
                       provenance())
        print(f"\nwrote {args.md}")
    return 0


if __name__ == "__main__":
    sys.exit(run_command(lambda: main()))
