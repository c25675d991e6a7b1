"""``python -m robomorph.evaluate``: a trained meta-model on a store, beside the baselines.

    python -m robomorph.evaluate --ckpt results/runs/ms/checkpoints/best.ckpt \\
        --data data/ms_test.zarr --out results/runs/ms/eval/ms_test \\
        --sweep-horizon 200:800:50 --sweep-context 20:200:20

Each trajectory's first ``context_len`` steps are the context; the next ``horizon`` steps
are predicted from the query torques alone. Writes ``metrics.json`` (both of the paper's
evaluation approaches for the model and every baseline, the sweeps, and the run's
meta-data), ``metrics.csv`` (one row per source, approach, channel and metric),
``table.md`` (per-channel table in the paper's fit colour convention) and PNG plots.

A checkpoint trained with ``data.normalization: paper_window`` (the paper's protocol) is
scored as the paper scored it: each window rescaled with its own query outputs' mean and
std. ``metrics.json`` then says ``"leaks_query_statistics": true`` and ``table.md`` says so
in its header.

The horizon sweep predicts with shorter query windows after the same context; the context
sweep keeps the predicted window fixed and gives the model only the last ``c`` steps
before it, so every point of it scores the same targets.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from dataclasses import dataclass

import numpy as np

from robomorph.core.errors import RoboMorphError
from robomorph.data.statistics import NormalizationError, leaks_query_statistics, query_output_stats
from robomorph.evaluation import metrics
from robomorph.evaluation import plots as eval_plots
from robomorph.evaluation.baselines import ARX, BASELINES, CEILINGS, hold
from robomorph.evaluation.tables import write_csv, write_table


@dataclass
class Window:
    """What one evaluation scores: ``n`` trajectories split at ``context_len``."""

    u: np.ndarray  # (N, context_len + horizon, n_u)
    y: np.ndarray  # (N, context_len + horizon, n_y)
    context_len: int
    horizon: int
    u_names: list[str]
    y_names: list[str]
    dt: float
    attrs: dict
    params: np.ndarray  # (N, P) the stored physical parameters (P may be 0)

    def split(self, context_len: int | None = None, horizon: int | None = None):
        """``u_ctx, y_ctx, u_query, y_query`` with the query always starting at ``self.context_len``."""
        c, h, c0 = context_len or self.context_len, horizon or self.horizon, self.context_len
        return self.u[:, c0 - c:c0], self.y[:, c0 - c:c0], self.u[:, c0:c0 + h], self.y[:, c0:c0 + h]


def load_window(data: str, context_len: int, horizon: int, n: int | None, info: dict | None,
                n_u: int, n_y: int) -> Window:
    """Reads and checks the first ``n`` trajectories of a store against the model.

    Raises:
        ValueError: empty store, channels that differ from the checkpoint's, a window longer
            than the trajectories, or non-finite values (the trajectories are named).
    """
    from robomorph.data.store import open_store  # noqa: PLC0415

    ds = open_store(data, allow_incomplete=True)
    total = int(ds.attrs.get("n", 0))
    if total == 0:
        raise ValueError(f"{data} holds no trajectories: generate or import data into it first")
    ds = open_store(data)  # a half-written store: the error says how to finish it
    if info is not None:
        for what, ours, theirs in (("u_names", ds.u_names, info["u_names"]), ("y_names", ds.y_names, info["y_names"])):
            if list(ours) != list(theirs):
                raise ValueError(f"{data} has {what} {list(ours)} but the checkpoint was trained on {list(theirs)}")
    elif (len(ds.u_names), len(ds.y_names)) != (n_u, n_y):
        raise ValueError(f"{data} has n_u={len(ds.u_names)}, n_y={len(ds.y_names)} but the checkpoint expects "
                         f"n_u={n_u}, n_y={n_y}")
    if context_len < 1 or horizon < 1 or context_len + horizon > ds.steps:
        raise ValueError(f"context_len {context_len} + horizon {horizon} must fit in the store's T={ds.steps} steps "
                         "(both >= 1): pass shorter --context-len / --horizon")
    rows = slice(0, min(n or total, total))
    u = ds.read("u", rows)[:, : context_len + horizon]
    y = ds.read("y", rows)[:, : context_len + horizon]
    bad = np.flatnonzero(~(np.isfinite(u).all((1, 2)) & np.isfinite(y).all((1, 2))))
    if len(bad):
        raise ValueError(f"{data}: trajectories {bad[:10].tolist()} hold NaN or inf in the evaluated window; "
                         "drop them (robomorph.merge) or fix the import")
    return Window(u, y, context_len, horizon, list(ds.u_names), list(ds.y_names), ds.dt, ds.attrs,
                  ds.read("params", rows))


def predict(predictor, u_ctx, y_ctx, u_query, batch_size: int, desc: str = "model", y_query=None) -> np.ndarray:
    """The model's predictions in batches, with a progress bar on stderr.

    ``y_query`` (the true outputs) is read only by a ``paper_window`` model, which needs
    their statistics (the paper's protocol); any other model never receives them.
    """
    from tqdm.auto import tqdm  # noqa: PLC0415

    leaks = getattr(predictor, "leaks_query_statistics", False)
    if leaks and y_query is None:
        raise NormalizationError("a paper_window model needs the query outputs' statistics: pass y_query to predict()")
    out = []
    for s in tqdm(range(0, len(u_ctx), batch_size), desc=desc, unit="batch", leave=False,
                  disable=not sys.stderr.isatty() and len(u_ctx) <= batch_size):
        part = slice(s, s + batch_size)
        stats = query_output_stats(y_query[part]) if leaks else None
        out.append(predictor.simulate(u_ctx[part], y_ctx[part], u_query[part], y_query_stats=stats))
    return np.concatenate(out).astype(np.float64)


def run_baselines(w: Window, names: tuple[str, ...], arx_orders: tuple[int, int]) -> tuple[dict, dict, dict]:
    """Predictions of the baselines that apply, the reasons of those skipped, and notes."""
    u_ctx, y_ctx, u_q, _ = w.split()
    preds, skipped, notes = {}, {}, {}
    for name in names:
        if name == "hold":
            preds[name] = hold(u_ctx, y_ctx, u_q).astype(np.float64)
        elif name == "arx":
            arx = ARX(*arx_orders)
            try:
                preds[name] = arx(u_ctx, y_ctx, u_q)
                notes["arx"] = {"na": arx.na, "nb": arx.nb, "diverged_held": arx.diverged}
            except ValueError as exc:
                skipped[name] = str(exc)
        elif name in ("nominal_physics", "true_physics"):
            from robomorph.evaluation.physics import NominalPhysics, NotApplicable, check_params  # noqa: PLC0415

            try:
                sim = NominalPhysics(w.attrs)
                if name == "true_physics":
                    check_params(w.attrs)
            except NotApplicable as exc:
                skipped[name] = str(exc)
                continue
            params = w.params if name == "true_physics" else None
            preds[name] = _batched(sim, u_ctx, y_ctx, u_q, name.replace("_", " "), params=params)
        else:
            raise ValueError(f"unknown baseline {name!r}; choose from {BASELINES + CEILINGS}")
    return preds, skipped, notes


def _batched(fn, u_ctx, y_ctx, u_q, desc: str, size: int = 16, params=None) -> np.ndarray:
    from tqdm.auto import tqdm  # noqa: PLC0415

    parts = [fn(u_ctx[s:s + size], y_ctx[s:s + size], u_q[s:s + size],
                params=None if params is None else params[s:s + size])
             for s in tqdm(range(0, len(u_ctx), size), desc=desc, unit="batch", leave=False)]
    return np.concatenate(parts).astype(np.float64)


def _summary(y, yhat) -> dict:
    """Channel-mean R^2 and FIT: ``r2``/``fit`` by approach 1, ``r2_a2``/``fit_a2`` by approach 2."""
    a2 = [np.asarray(f(y.reshape(1, -1, y.shape[-1]), yhat.reshape(1, -1, y.shape[-1])))[0].mean()
          for f in (metrics.r2, metrics.fit_index)]
    return {"r2": float(metrics.approach1_mean(y, yhat, "r2")), "fit": float(metrics.approach1_mean(y, yhat, "fit")),
            "r2_a2": float(a2[0]), "fit_a2": float(a2[1])}


def sweep_horizon(predictor, w: Window, horizons: list[int], baselines: dict, batch_size: int) -> list[dict]:
    """Mean approach-1 R^2 / FIT for each horizon, same context (baselines are causal: truncated)."""
    rows = []
    for h in horizons:
        u_ctx, y_ctx, u_q, y_q = w.split(horizon=h)
        y_q = y_q.astype(np.float64)
        row = {"horizon": h, "model": _summary(y_q, predict(predictor, u_ctx, y_ctx, u_q, batch_size, f"horizon {h}", y_q))}
        row.update({name: _summary(y_q, p[:, :h]) for name, p in baselines.items()})
        rows.append(row)
    return rows


def sweep_context(predictor, w: Window, contexts: list[int], batch_size: int) -> list[dict]:
    """Mean approach-1 R^2 / FIT for each context length, same predicted window."""
    rows = []
    for c in contexts:
        u_ctx, y_ctx, u_q, y_q = w.split(context_len=c)
        y_q = y_q.astype(np.float64)
        rows.append({"context_len": c, "model": _summary(y_q, predict(predictor, u_ctx, y_ctx, u_q, batch_size,
                                                                      f"context {c}", y_q)),
                     "hold": _summary(y_q, hold(u_ctx, y_ctx, u_q))})
    return rows


def parse_range(text: str | None, low: int, high: int, what: str) -> list[int]:
    """``a:b:s`` (b included) or ``a,b,c`` into a list within ``[low, high]``."""
    if not text:
        return []
    try:
        if ":" in text:
            a, b, s = (int(v) for v in text.split(":"))
            values = list(range(a, b + 1, s))
        else:
            values = [int(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--sweep-{what} takes start:stop:step or a comma list of integers, got {text!r}") from None
    if not values or min(values) < low or max(values) > high:
        raise ValueError(f"--sweep-{what} {text!r} must lie within [{low}, {high}]")
    return values


class EvaluationError(RoboMorphError, ValueError):
    """Evaluation settings that cannot work; the message names the flag."""


def check_counts(**values: int | None) -> None:
    """Refuses a given (not None) step or trajectory count below 1: ``--context-len 0`` would
    otherwise fall back to the checkpoint's length without a word."""
    for name, value in values.items():
        if value is not None and value < 1:
            flag = "--" + name.replace("_", "-")
            raise EvaluationError(f"{flag} {value}: give a positive number, or leave it out for the default")


def evaluate(ckpt: str, data: str, out: str, context_len: int | None = None, horizon: int | None = None,
             n: int | None = None, baselines: tuple[str, ...] = BASELINES, sweep_horizon_spec: str | None = None,
             sweep_context_spec: str | None = None, batch_size: int = 64, device: str | None = None,
             samples: int = 3, arx_orders: tuple[int, int] = (2, 2), seed: int = 0,
             normalization: str | None = None) -> dict:
    """Evaluates a checkpoint on a store and writes every output file into ``out``.

    Args:
        normalization: when given, the normalization the checkpoint must have been trained
            with (``train_stats`` or ``paper_window``); default: whatever it was trained with.

    Returns:
        The ``metrics.json`` content.
    """
    from robomorph.predictor import Predictor  # noqa: PLC0415  (torch only here)

    check_counts(context_len=context_len, horizon=horizon, n=n, batch_size=batch_size)
    for name in baselines:
        if name not in BASELINES + CEILINGS:
            raise ValueError(f"unknown baseline {name!r}; choose from {BASELINES + CEILINGS}")
    predictor = Predictor.from_checkpoint(ckpt, device=device)
    if normalization is not None and normalization != predictor.normalization:
        raise NormalizationError(f"{ckpt} was trained with normalization {predictor.normalization!r}, not "
                                 f"{normalization!r}: the normalization is fixed at training time (data.normalization)")
    info = predictor.data_info
    context_len = context_len or (info or {}).get("context_len")
    horizon = horizon or (info or {}).get("horizon")
    if context_len is None or horizon is None:
        raise ValueError(f"{ckpt} does not record its training window: pass --context-len and --horizon")
    w = load_window(data, int(context_len), int(horizon), n, info, predictor.n_u, predictor.n_y)
    horizons = parse_range(sweep_horizon_spec, 1, w.horizon, "horizon")
    contexts = parse_range(sweep_context_spec, 1, w.context_len, "context")
    patch = int(predictor.module.hparams.get("patch", 1))
    odd = [c for c in [w.context_len, *contexts] if c % patch]
    if odd:
        raise ValueError(f"context lengths must be multiples of the model's patch ({patch} steps per token): "
                         f"{odd} are not (--context-len / --sweep-context)")
    os.makedirs(out, exist_ok=True)

    u_ctx, y_ctx, u_q, y_q = w.split()
    y_q = y_q.astype(np.float64)
    preds = {"model": predict(predictor, u_ctx, y_ctx, u_q, batch_size, y_query=y_q)}
    base, skipped, notes = run_baselines(w, tuple(baselines), arx_orders)
    preds.update(base)
    names = w.y_names
    result = {"approach1": metrics.approach1(y_q, preds["model"], names),
              "approach2": metrics.approach2(y_q, preds["model"], names),
              "baselines": {b: {"approach1": metrics.approach1(y_q, p, names), "approach2": metrics.approach2(y_q, p, names)}
                            for b, p in base.items()},
              "skipped_baselines": skipped,
              "meta": {"ckpt": ckpt, "data": data, "context_len": w.context_len,
                       "horizon": w.horizon, "n": len(w.u), "dt": w.dt, "y_names": names, "u_names": w.u_names,
                       "device": str(predictor.device), "baseline_notes": notes,
                       "domain": w.attrs.get("domain"), "task": w.attrs.get("task"),
                       "normalization": predictor.normalization},
              # The paper's protocol scales each window with its query outputs' statistics: say so first.
              "leaks_query_statistics": leaks_query_statistics(predictor.normalization)}
    sweeps = {}
    if horizons:
        sweeps["horizon"] = sweep_horizon(predictor, w, horizons, base, batch_size)
        eval_plots.plot_sweep(os.path.join(out, "sweep_horizon.png"), sweeps["horizon"], "horizon")
    if contexts:
        sweeps["context"] = sweep_context(predictor, w, contexts, batch_size)
        eval_plots.plot_sweep(os.path.join(out, "sweep_context.png"), sweeps["context"], "context_len")
    result["sweeps"] = sweeps
    eval_plots.write_all(out, y_ctx, y_q, preds, names, w.dt, samples, seed)
    write_csv(os.path.join(out, "metrics.csv"), result)
    write_table(os.path.join(out, "table.md"), result)
    _write_json(os.path.join(out, "metrics.json"), result)
    return result


def _write_json(path: str, obj: dict) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, allow_nan=True)
    os.replace(tmp, path)


def default_out(ckpt: str, data: str) -> str:
    """``<run>/eval/<store name>`` for a checkpoint in ``<run>/checkpoints/``."""
    run = os.path.dirname(os.path.dirname(os.path.abspath(ckpt)))
    return os.path.join(run, "eval", os.path.basename(os.path.normpath(data)).removesuffix(".zarr"))


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(prog="python -m robomorph.evaluate", description=__doc__.split("\n")[0])
    p.add_argument("--ckpt", required=True, help="checkpoint written by robomorph.fit")
    p.add_argument("--data", required=True, help="store to evaluate on (.zarr)")
    p.add_argument("--out", help="output folder (default: <run>/eval/<store name>)")
    p.add_argument("--context-len", type=int, help="context steps (default: the checkpoint's)")
    p.add_argument("--horizon", type=int, help="predicted steps (default: the checkpoint's)")
    p.add_argument("--n", type=int, help="evaluate only the first N trajectories")
    p.add_argument("--baselines", default=",".join(BASELINES),
                   help=f"comma list from {BASELINES + CEILINGS}, or 'none' (true_physics reads the hidden "
                        "parameters: a predictability ceiling, not a competitor)")
    p.add_argument("--sweep-horizon", help="horizons to sweep, e.g. 200:800:50 or 100,400,800")
    p.add_argument("--sweep-context", help="context lengths to sweep, e.g. 20:200:20")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--device", help="cpu, cuda, ... (default: cuda when available)")
    p.add_argument("--samples", type=int, default=3, help="sample trajectories to plot")
    p.add_argument("--arx-orders", default="2,2", help="ARX output and input lags na,nb")
    p.add_argument("--seed", type=int, default=0, help="picks the plotted sample trajectories")
    p.add_argument("--normalization", choices=("train_stats", "paper_window"),
                   help="require the checkpoint to have been trained with this normalization (default: its own)")
    a = p.parse_args(argv)
    baselines = () if a.baselines.strip() in ("", "none") else tuple(s.strip() for s in a.baselines.split(","))
    out = a.out or default_out(a.ckpt, a.data)
    try:
        orders = tuple(int(v) for v in a.arx_orders.split(","))
        if len(orders) != 2:
            raise ValueError
    except ValueError:
        p.error(f"--arx-orders takes two integers na,nb, got {a.arx_orders!r}")
    try:
        res = evaluate(a.ckpt, a.data, out, a.context_len, a.horizon, a.n, baselines, a.sweep_horizon,
                       a.sweep_context, a.batch_size, a.device, a.samples, orders, a.seed, a.normalization)
    except (ValueError, FileNotFoundError) as exc:
        sys.exit(f"error: {exc}")
    print(summary_text(res, out))


def summary_text(res: dict, out: str) -> str:
    """A few lines for the terminal: mean approach-1 scores of the model and the baselines."""
    m, meta = res["approach1"]["mean"], res["meta"]
    lines = [f"{meta['n']} trajectories, context {meta['context_len']}, horizon {meta['horizon']} (approach 1 mean):"]
    if res.get("leaks_query_statistics"):
        lines.append(f"  normalization {meta.get('normalization')}: scores use the query outputs' statistics (the "
                     "paper's protocol), not those of a deployable model")
    lines.append(f"  {'model':16s} R2 {m['r2']['mean']:8.3f}  FIT {m['fit']['mean']:8.2f}  RMSE {m['rmse']['mean']:.4g}")
    for b, r in res["baselines"].items():
        mb = r["approach1"]["mean"]
        lines.append(f"  {b:16s} R2 {mb['r2']['mean']:8.3f}  FIT {mb['fit']['mean']:8.2f}  RMSE {mb['rmse']['mean']:.4g}")
    lines += [f"  skipped {b}: {why}" for b, why in res["skipped_baselines"].items()]
    lines.append(f"written: {out}/ (metrics.json, metrics.csv, table.md, *.png)")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
