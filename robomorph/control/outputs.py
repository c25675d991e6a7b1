"""What a comparison of controllers writes: ``metrics.json``, ``table.md`` and two plots.

Figures per controller, over the tracking phase of its episodes (warm-up excluded):

- ``ee_rms_mm`` and ``ee_max_mm``: EE distance to the reference, RMS over the frames of the
  episodes that did not fail (pooled), and the largest; ``ee_rms_mm_median_robot``: the median
  over those episodes of each one's RMS (one hard robot weighs less);
- ``torque_rms_nm``: RMS of the commands over joints and frames;
- ``saturation_events``: frames with a command at a torque limit;
- ``failed_episodes`` and ``failures``: episodes ended by a contact, a joint limit or a
  diverged state (robot and reason);
- ``replan_ms_median`` and ``replan_ms_p95``: wall time of one re-plan, identification included.
"""

from __future__ import annotations

import os

import numpy as np

from robomorph.core.atomic import save_figure, write_json
from robomorph.core.results import markdown_table, write_markdown

_COLORS = {"osc": "C0", "mpc:model": "C1", "mpc:nominal_physics": "C3", "mpc:identified_physics": "C5",
           "mpc:true_physics": "C4"}


def summarize(results: list, controllers: list[str]) -> dict:
    """``{controller: figures}`` (see the module's docstring) from episode results."""
    out = {}
    for name in controllers:
        eps = sorted((r for r in results if r.controller == name), key=lambda r: r.robot)
        ok = [r for r in eps if r.failure is None]
        err = np.concatenate([r.error_mm for r in ok]) if ok else np.zeros(0)
        torque = np.concatenate([r.torque[r.warmup:r.frames] for r in eps]) if eps else np.zeros((0, 1))
        ms = np.concatenate([np.asarray(r.replan_ms) for r in eps]) if eps else np.zeros(0)
        out[name] = {
            "ee_rms_mm": float(np.sqrt(np.mean(err ** 2))) if err.size else None,
            "ee_max_mm": float(err.max()) if err.size else None,
            "ee_rms_mm_median_robot": float(np.median([np.sqrt(np.mean(r.error_mm ** 2)) for r in ok])) if ok else None,
            "ee_rms_mm_per_robot": {str(r.robot): float(np.sqrt(np.mean(r.error_mm ** 2))) for r in ok},
            "torque_rms_nm": float(np.sqrt(np.mean(torque ** 2))) if torque.size else None,
            "saturation_events": int(sum(r.saturated for r in eps)),
            "episodes": len(eps),
            "failed_episodes": len(eps) - len(ok),
            "failures": [{"robot": r.robot, "reason": r.failure, "frame": r.frames} for r in eps if r.failure],
            "replan_ms_median": float(np.median(ms)) if ms.size else None,
            "replan_ms_p95": float(np.percentile(ms, 95)) if ms.size else None,
            "reads_hidden_parameters": name == "mpc:true_physics",
        }
        seconds = [r.notes.get("seconds") for r in eps if r.notes.get("seconds") is not None]
        if seconds:
            out[name]["identification_s_per_episode"] = float(np.mean(seconds))
    return out


def table(metrics: dict) -> str:
    """The Markdown table of :func:`summarize`'s figures, one row per controller."""
    def fmt(v, spec=".2f"):
        return "—" if v is None else format(v, spec)

    rows = [[name + (" (ceiling: reads the hidden parameters)" if m["reads_hidden_parameters"] else ""),
             fmt(m["ee_rms_mm"]), fmt(m["ee_max_mm"], ".1f"), fmt(m["torque_rms_nm"]), m["saturation_events"],
             f"{m['failed_episodes']}/{m['episodes']}", fmt(m["replan_ms_median"], ".1f"),
             fmt(m["replan_ms_p95"], ".1f")] for name, m in metrics.items()]
    return markdown_table(["controller", "EE RMS [mm]", "EE max [mm]", "torque RMS [N m]", "saturated frames",
                           "failed", "re-plan median [ms]", "re-plan p95 [ms]"], rows, align="lrrrrrrr")


def plot_errors(path: str, results: list, dt: float) -> str:
    """Tracking error against time (median over robots, and the 10-90 % band) per controller."""
    from robomorph.evaluation.plots import _plt  # noqa: PLC0415

    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for name in dict.fromkeys(r.controller for r in results):
        eps = [r for r in results if r.controller == name and r.failure is None]
        if not eps:
            continue
        n = min(len(r.error_mm) for r in eps)
        err = np.stack([r.error_mm[:n] for r in eps])
        t = np.arange(n) * dt
        color = _COLORS.get(name, None)
        ax.plot(t, np.median(err, axis=0), color=color, label=name)
        ax.fill_between(t, *np.percentile(err, [10, 90], axis=0), color=color, alpha=0.15, lw=0)
    ax.set_xlabel("time since the controller took over [s]")
    ax.set_ylabel("EE tracking error [mm]")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path


def plot_paths(path: str, results: list, robot: int) -> str:
    """The EE path of every controller against the reference on one robot, in 3-D."""
    from robomorph.evaluation.plots import _plt  # noqa: PLC0415

    plt = _plt()
    fig = plt.figure(figsize=(6, 5))
    ax = fig.add_subplot(projection="3d")
    eps = [r for r in results if r.robot == robot]
    if eps:
        ref = eps[0].ref[eps[0].warmup:]
        ax.plot(*ref.T, color="k", lw=2.0, alpha=0.4, label="reference")
    for r in eps:
        ax.plot(*r.ee[r.warmup:r.frames].T, color=_COLORS.get(r.controller), lw=1.0, label=r.controller)
    if eps:  # one scale on every axis: a millimetre looks the same along x as along z
        pts = np.concatenate([eps[0].ref[eps[0].warmup:]] + [r.ee[r.warmup:r.frames] for r in eps])
        mid, half = (pts.max(0) + pts.min(0)) / 2, float((pts.max(0) - pts.min(0)).max()) / 2 + 1e-3
        for setter, centre in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), mid):
            setter(centre - half, centre + half)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title(f"robot {robot}: tracking phase")
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)
    return path


def write(out_dir: str, results: list, controllers: list[str], config: dict, prov: dict, dt: float) -> dict:
    """Writes ``metrics.json``, ``table.md``, ``errors.png`` and ``paths.png`` into ``out_dir``."""
    os.makedirs(out_dir, exist_ok=True)
    metrics = summarize(results, controllers)
    write_json(os.path.join(out_dir, "metrics.json"), {**metrics, "_config": config, "_provenance": prov})
    text = (f"# Closed-loop control: {config['task']}, {config['robots']} robots ({config['uncertainty']} "
            f"uncertainty)\n\n{table(metrics)}\n\nEE RMS pools the tracking phase of the episodes that did not fail; "
            "a failed episode (contact, joint limit, divergence) stops there and counts under *failed*.\n")
    write_markdown(os.path.join(out_dir, "table.md"), text, prov)
    plot_errors(os.path.join(out_dir, "errors.png"), results, dt)
    plot_paths(os.path.join(out_dir, "paths.png"), results, min(r.robot for r in results))
    return metrics
