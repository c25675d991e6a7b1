"""The dashboard's closed-loop control section, read from a ``robomorph control`` output folder.

Only the folder's files are read (``metrics.json``, ``errors.png``, ``paths.png``): the
dashboard never imports the control code, and a folder from another version still shows.
"""

from __future__ import annotations

import json
from pathlib import Path

from robomorph.reporting import html as rh

_COLUMNS = (("EE RMS [mm]", "ee_rms_mm", ".2f"), ("median robot [mm]", "ee_rms_mm_median_robot", ".2f"),
            ("EE max [mm]", "ee_max_mm", ".1f"), ("torque RMS [N m]", "torque_rms_nm", ".2f"),
            ("saturated frames", "saturation_events", "d"), ("re-plan median [ms]", "replan_ms_median", ".1f"),
            ("re-plan p95 [ms]", "replan_ms_p95", ".1f"))


def _cell(value, spec: str) -> rh.Cell:
    plain = isinstance(value, (int, float)) and not isinstance(value, bool) and (spec != "d" or isinstance(value, int))
    return rh.Cell(format(value, spec) if plain else "—", cls="num")


def control_view(folder: str | Path | None) -> dict | None:
    """What the template shows of a control folder, or None when it holds no ``metrics.json``.

    Returns:
        ``{"path", "table", "config", "provenance", "figures", "warnings"}``; an unreadable
        file gives a warning instead of an error (the rest of the report still renders).
    """
    if folder is None:
        return None
    folder = Path(folder)
    path = folder / "metrics.json"
    if not path.is_file():
        return None
    warnings: list[str] = []
    guard = rh.FolderGuard(folder, warnings, "control folder")
    try:
        metrics = json.loads(path.read_text()) if guard.allows(path) else None
    except (OSError, ValueError) as exc:
        metrics, reason = None, f"{path} is unreadable: {exc}"
    else:
        reason = None if metrics is None or isinstance(metrics, dict) else \
            f"{path} holds a {type(metrics).__name__}, not the metrics of robomorph control; not shown"
    if not isinstance(metrics, dict):
        return {"path": str(folder), "table": None, "config": {}, "provenance": {}, "figures": [],
                "warnings": warnings + ([reason] if reason else [])}
    rows = []
    for name, m in metrics.items():
        if name.startswith("_") or not isinstance(m, dict):
            continue
        label = name + (" (ceiling: reads the hidden parameters)" if m.get("reads_hidden_parameters") else "")
        cells = [rh.Cell(label)] + [_cell(m.get(key), spec) for _, key, spec in _COLUMNS]
        cells.append(rh.Cell(f"{m.get('failed_episodes', 0)}/{m.get('episodes', 0)}", cls="num"))
        rows.append(rh.Row(tuple(cells)))
    table = rh.Table(("controller", *(head for head, _, _ in _COLUMNS), "failed"), tuple(rows))
    figures = []
    for name, caption in (("errors.png", "EE tracking error against time (median over robots, 10-90 % band)"),
                          ("paths.png", "EE paths against the reference on the first robot")):
        png = folder / name
        data = guard.png(png, str(folder)) if guard.file(png) else None
        if data is not None:
            figures.append((rh.png_uri(data), caption))
    config = metrics.get("_config") if isinstance(metrics.get("_config"), dict) else {}
    shown = {k: config.get(k) for k in ("task", "robots", "uncertainty", "seed", "warmup", "duration", "ckpt",
                                          "physics_mode") if k in config}
    prov = metrics.get("_provenance") if isinstance(metrics.get("_provenance"), dict) else {}
    return {"path": str(folder), "table": table, "config": shown, "provenance": prov, "figures": figures,
            "warnings": warnings}
