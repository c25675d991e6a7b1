"""The HTML run report: content, self-containment, fit colours, robustness, and how Chromium renders it."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from robomorph.report import main
from robomorph.reporting.dashboard import ReportError, build_report, curves_figure, load_run, read_curves
from robomorph.reporting.html import fit_colour

ROOT = Path(__file__).resolve().parents[2]
CHANNELS = ("ee_x", "ee_y", "ee_z")
# Approach-1 mean FIT per source and channel, chosen to hit every colour band.
FITS = {"model": (95.0, 85.0, 65.0), "hold": (20.0, 25.0, 10.0), "arx": (70.0, 45.0, 35.0)}
HEADER = "epoch,lr,lr-AdamW/pg1,lr-AdamW/pg2,step,train/loss,val/fit,val/loss,val/r2"
CONFIG = """# lightning.pytorch==2.6.6
# see https://wandb.ai/some/project  <script>alert(1)</script>
seed_everything: 0
model:
  d_model: 64
  n_head: 4
  n_layer: 2
  patch: 10
data:
  context_len: 200
  horizon: 800
run: {name}
"""


# --- factories ---------------------------------------------------------------------------

def _approach(fits: tuple[float, ...], with_std: bool) -> dict:
    def entry(fit: float) -> dict:
        values = {"r2": 1 - (1 - fit / 100) ** 2, "rmse": 0.02 * (100 - fit) / 10, "nrmse": (100 - fit) / 100, "fit": fit}
        return {k: {"mean": v, "std": 0.1 * abs(v)} for k, v in values.items()} if with_std else values

    out = {"channels": dict(zip(CHANNELS, map(entry, fits)))}
    if with_std:
        out["mean"] = entry(sum(fits) / len(fits))
    return out


def _source(fits: tuple[float, ...]) -> dict:
    return {"approach1": _approach(fits, True), "approach2": _approach(tuple(f - 3.0 for f in fits), False)}


def make_metrics() -> dict:
    metrics = _source(FITS["model"])
    metrics["baselines"] = {name: _source(FITS[name]) for name in ("hold", "arx")}
    metrics["skipped_baselines"] = {"nominal_physics": "store has no nominal parameters"}
    metrics["meta"] = {"ckpt": "results/runs/alpha/checkpoints/best.ckpt", "data": "/data/heldout.zarr",
                       "context_len": 200, "horizon": 800, "n": 64, "y_names": list(CHANNELS), "baseline_notes": {}}
    return metrics


def make_png(seed: int = 0) -> bytes:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 1.5))
    fig.subplots().plot(np.random.default_rng(seed).normal(size=20))
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=50)
    return buf.getvalue()


def make_csv(steps: int = 5) -> str:
    """Sparse CSVLogger rows: lr rows, train rows and validation rows never share cells."""
    rows = [HEADER]
    for i in range(1, steps + 1):
        step = 10 * i - 1
        rows += [f",,1e-4,1e-4,{step},,,,", f"{i},1e-4,,,{step},{1.0 / i},,,"]
        if i % 2 == 0:
            rows.append(f"{i},,,,{step},,{40.0 + 10 * i},{1.2 / i},{0.1 * i}")
    return "\n".join(rows) + "\n"


def make_run(root: Path, name: str, *, config: bool = True, logs: bool = True, evals: tuple[str, ...] = ("heldout",)) -> Path:
    run = root / name
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "best.ckpt").write_bytes(b"\0" * 2048)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"\0" * 4096)
    if config:
        (run / "config.yaml").write_text(CONFIG.format(name=name))
    if logs:
        (run / "logs").mkdir()
        (run / "logs" / "metrics.csv").write_text(make_csv())
    for i, ev in enumerate(evals):
        folder = run / "eval" / ev
        folder.mkdir(parents=True)
        (folder / "metrics.json").write_text(json.dumps(make_metrics()))
        (folder / "rollout.png").write_bytes(make_png(i))
        (folder / "table.md").write_text("| channel | fit |\n|---|---|\n| ee_x | 95.0 |\n")
    return run


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """A report over a full run, a run with logs but no evaluation, and a bare run."""
    root = tmp_path_factory.mktemp("report") / "runs"
    make_run(root, "alpha")
    make_run(root, "beta", evals=())
    make_run(root, "gamma", config=False, logs=False, evals=())
    (root / "not_a_run").mkdir()  # a stray folder with none of a run's files is ignored
    return Path(build_report(str(root), str(root.parent / "out" / "report.html")))


# --- content ------------------------------------------------------------------------------

def test_report_is_self_contained(report):
    page = report.read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", page, re.I)
    assert not re.search(r"<script|<link[^>]+stylesheet|@import|url\(", page, re.I)
    sources = re.findall(r'<img src="([^"]*)"', page)
    assert len(sources) == 2  # the shared curves figure and alpha's rollout.png
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"


def test_report_shows_every_run_channel_baseline_and_fact(report):
    page = report.read_text()
    for text in ("alpha", "beta", "gamma", *CHANNELS, "hold", "arx", "nominal_physics", "store has no nominal parameters",
                 "/data/heldout.zarr", "y_names: <code>ee_x, ee_y, ee_z</code>", "rollout.png", "best.ckpt",
                 "2.0 KiB", "4.0 KiB", "no evaluations", "no logs/metrics.csv"):
        assert text in page, text
    assert "not_a_run" not in page
    overview = page.split("<h2>Overview</h2>")[1].split("<h2>")[0]
    assert overview.count("<tr>") == 2 + 3  # two header rows + one row per run (alpha has one evaluation)
    for value in ("64", "200", "800"):  # d_model, context_len, horizon from config.yaml
        assert f"<td>{value}</td>" in overview
    assert "arx: 47.0" in overview  # best baseline by pooled FIT over the channels ((67+42+32)/3)


def test_paper_window_evaluations_are_marked_and_others_are_not(tmp_path):
    root = tmp_path / "runs"
    make_run(root, "clean")
    leaky = make_run(root, "leaky", evals=("test0",))
    path = leaky / "eval" / "test0" / "metrics.json"
    metrics = json.loads(path.read_text())
    metrics["leaks_query_statistics"] = True
    metrics["meta"]["normalization"] = "paper_window"
    path.write_text(json.dumps(metrics))
    config = leaky / "config.yaml"
    config.write_text(config.read_text().replace("horizon: 800\n", "horizon: 800\n  normalization: paper_window\n"))
    page = Path(build_report(str(root), str(tmp_path / "report.html"))).read_text()
    rows = page.split("<h2>Overview</h2>")[1].split("<h2>")[0].split("<tr>")[1:]
    marked = [r for r in rows if "paper_window: uses query statistics" in r]
    assert len(marked) == 1 and "leaky" in marked[0] and "test0" in marked[0]
    assert "<td>paper_window</td>" in marked[0]  # the run's normalization, a fact from its config
    sections = page.split('<section id="run-')[1:]
    assert "the query outputs&#39; statistics" in sections[1] and "query outputs" not in sections[0]


def test_each_evaluation_says_what_predicted_it_marks_diverged_baselines_and_folds_its_metadata(tmp_path):
    root = tmp_path / "runs"
    make_run(root, "blackbox")
    hybrid = make_run(root, "hybrid")
    path = hybrid / "eval" / "heldout" / "metrics.json"
    metrics = json.loads(path.read_text())
    metrics["meta"]["physics"] = {"mode": "regression", "observer": True}
    metrics["meta"]["baseline_notes"] = {"arx": {"na": 2, "nb": 2, "diverged_held": 40}}
    path.write_text(json.dumps(metrics))
    page = Path(build_report(str(root), str(tmp_path / "report.html"))).read_text()
    caption = page.split('<h2 id="curves">Training curves</h2>')[1]  # after the predictions, saying whose
    assert page.index("<h2>Runs</h2>") < page.index('<h2 id="curves">') and "all of the network&#39;s decoder" in caption
    assert "blackbox: its evaluations are the decoder&#39;s predictions" in caption
    assert "hybrid: its evaluations were predicted by the hybrid (regression), which does not read the decoder" in caption
    blackbox, hyb = page.split('<section id="run-')[1:3]
    assert "Predicted by the network&#39;s decoder (the black-box model)" in blackbox
    assert "Predicted by the hybrid, physics mode regression" in hyb and "It reads no network" in hyb
    assert "Baseline arx: 40 of 64 trajectories diverged: held instead" in hyb and "diverged" not in blackbox
    for section in (blackbox, hyb):  # the evaluation's metadata sits behind a fold, not above its tables
        fold = section.split("<summary>run information (")[1].split("</details>")[0]
        assert "context_len: <code>200</code>" in fold and section.index("<details><summary>run information") < \
            section.index("<table")
        assert section.count("context_len: <code>200</code>") == 1


def test_report_escapes_file_text(report):
    page = report.read_text()
    assert "<script>alert(1)</script>" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in page


def test_fit_and_r2_cells_are_coloured_by_fit(report):
    page = report.read_text()
    cells = re.findall(r'<td(?: class="[^"]*")?(?: style="background:([^"]+)")?>([^<]*)</td>', page)
    r2, fit = re.compile(r"-?\d+\.\d{3}( ± \d+\.\d{3})?"), re.compile(r"-?\d+\.\d( ± \d+\.\d)?")
    pairs = [(a, b) for a, b in zip(cells, cells[1:]) if r2.fullmatch(a[1]) and fit.fullmatch(b[1])]
    # alpha: 4 rows (3 channels + all channels) x 3 sources x 2 approaches, plus its overview row's two pairs.
    assert len(pairs) == 4 * 3 * 2 + 2
    for (r2_colour, _), (fit_colour_seen, text) in pairs:
        assert r2_colour == fit_colour_seen == fit_colour(float(text.split()[0]))
    seen = {c for (c, _), _ in pairs}
    assert seen == {fit_colour(f) for f in (95, 85, 65, 45, 20)}  # every band shows up
    assert all(f"background:{c}" in page.split("Fit-index colours")[1][:1500] for c in seen)  # the legend


def test_read_curves_keeps_only_logged_points(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text(make_csv(steps=4))
    curves, notes = read_curves(path)
    assert curves["train/loss"] == ([9.0, 19.0, 29.0, 39.0], [1.0, 0.5, 1 / 3, 0.25])
    assert curves["val/loss"] == ([19.0, 39.0], [0.6, 0.3])
    assert notes == []
    path.write_text("epoch,step,train/loss\n0,9,0.5\n0,19,oops\n")
    curves, notes = read_curves(path)
    assert curves == {"train/loss": ([9.0], [0.5])}
    assert any("val/r2" in n for n in notes) and any("non-numeric" in n for n in notes)


# --- robustness ---------------------------------------------------------------------------

def test_negative_losses_are_plotted_on_a_linear_axis(tmp_path):
    """A Gaussian NLL goes below zero: every logged point must be drawn, none dropped by a log axis."""
    root = tmp_path / "runs"
    nll = make_run(root, "nll", evals=())
    rows = [HEADER] + [f"0,1e-4,,,{s},{1.5 - 0.5 * i},,," for i, s in enumerate((9, 19, 29, 39, 49, 59))]
    rows += [f"0,,,,{s},,50.0,{v},0.5" for s, v in ((19, 0.4), (39, -0.8), (59, -2.5))]
    (nll / "logs" / "metrics.csv").write_text("\n".join(rows) + "\n")
    make_run(root, "positive", evals=())
    runs = [load_run(root / name) for name in ("nll", "positive")]
    fig = curves_figure(runs)
    axes = {ax.get_title().split(" ")[1]: ax for ax in fig.axes}
    assert all(ax.get_title().startswith("decoder ") for ax in fig.axes)  # whose curves they are
    for key, want in (("train/loss", [1.5, 1.0, 0.5, 0.0, -0.5, -1.0]), ("val/loss", [0.4, -0.8, -2.5])):
        ax = axes[key]
        assert ax.get_yscale() == "linear" and "linear scale" in ax.get_title()
        drawn = {line.get_label(): line.get_xydata() for line in ax.get_lines()}
        assert drawn["nll"][:, 1].tolist() == want  # every point, the negative ones included
        assert len(drawn["positive"]) == len(runs[1].curves[key][0])
    # Losses that are all positive keep the log axis.
    only_positive = curves_figure(runs[1:])
    assert [ax.get_yscale() for ax in only_positive.axes] == ["log", "log", "linear"]
    page = Path(build_report(str(root), str(tmp_path / "report.html"))).read_text()
    assert "linear otherwise" in page


def test_the_report_follows_no_symlink_out_of_the_run_and_embeds_only_pngs(tmp_path):
    root = tmp_path / "runs"
    run = make_run(root, "alpha")
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_text("SECRET-TOKEN root:x:0:0")
    (outside / "real.png").write_bytes(make_png(3))  # a real image, but not the run's
    ev = run / "eval" / "heldout"
    (ev / "sample_0.png").symlink_to("/etc/passwd")
    (ev / "sample_1.png").symlink_to(outside / "real.png")
    (ev / "sample_2.png").write_text("SECRET-TOKEN not an image")  # inside, but not a PNG
    (ev / "sample_3.png").symlink_to(ev / "rollout.png")  # a link that stays inside is fine
    (run / "config.yaml").unlink()
    (run / "config.yaml").symlink_to(outside / "secret.txt")
    (run / "eval" / "linked").symlink_to(outside, target_is_directory=True)
    (root / "elsewhere").symlink_to(make_run(tmp_path / "other", "elsewhere"), target_is_directory=True)
    page = Path(build_report(str(root), str(tmp_path / "report.html"))).read_text()
    assert "SECRET-TOKEN" not in page and "root:x:0:0" not in page
    uris = re.findall(r'<img src="data:image/png;base64,([^"]*)"', page)
    embedded = [base64.b64decode(u) for u in uris]
    assert all(png.startswith(b"\x89PNG\r\n\x1a\n") for png in embedded)
    assert len(embedded) == 3  # the curves, rollout.png and its in-run link sample_3.png
    assert (outside / "real.png").read_bytes() not in embedded and (ev / "rollout.png").read_bytes() in embedded
    warnings = re.findall(r'<div class="warn">([^<]*)</div>', page)
    for name in ("sample_0.png", "sample_1.png", "config.yaml", "eval/linked"):
        assert any(name in w and "outside the run folder" in w for w in warnings), name
    assert any("sample_2.png is not a PNG image" in w for w in warnings)
    assert any("elsewhere" in w and "symbolic link leading outside" in w for w in warnings)



def test_malformed_files_become_warnings(tmp_path, capsys):
    root = tmp_path / "runs"
    run = make_run(root, "broken", evals=("bad_json", "bad_shape"))
    (run / "eval" / "bad_json" / "metrics.json").write_text('{"approach1": {"channels": ')
    (run / "eval" / "bad_shape" / "metrics.json").write_text("[1, 2, 3]")
    (run / "config.yaml").write_text("model: [unclosed\n")
    (run / "logs" / "metrics.csv").write_text("epoch,step\n")
    page = Path(build_report(str(root), str(tmp_path / "r.html"))).read_text()
    warnings = re.findall(r'<div class="warn">([^<]*)</div>', page)
    assert any("bad_json/metrics.json is malformed" in w for w in warnings)
    assert any("bad_shape/metrics.json is malformed" in w for w in warnings)
    assert any("config.yaml is not valid YAML" in w for w in warnings)
    assert "model: [unclosed" in page  # the raw config is still shown
    err = capsys.readouterr().err
    assert err.count("report: warning: broken:") == 3


def scored_metrics(seed: int = 0) -> dict:
    """A metrics.json as evaluate writes it (the evaluation's own functions) for the case issue 61 §5 found: a
    model whose joint error is far below hold's, on windows where one channel (ee_qz) rests in most of them,
    so that its per-window FIT is about −1000 there and rules the paper's mean."""
    from robomorph.evaluation import metrics as ev_metrics
    from robomorph.evaluation.horizons import horizon_report

    names = ["ee_x", "ee_y", "ee_z", "ee_qx", "ee_qy", "ee_qz", "ee_qw"] + [f"q{i}" for i in range(7)]
    rng, t = np.random.default_rng(seed), np.arange(-1, 121) / 60  # the context's last two samples, then the query
    full = np.sin(2 * np.pi * 0.4 * t[None, :, None] + rng.uniform(0, 6.3, size=(16, 1, len(names))))
    full[:12, :, names.index("ee_qz")] = 0.3  # at rest in 12 of the 16 windows
    full = full + 3e-5 * rng.normal(size=full.shape)  # the sensors' noise
    y, steps = full[:, 2:], t[None, 2:, None]
    err = steps * 0.002 * rng.normal(size=(16, 1, len(names)))  # growing with the horizon
    model, hold = y + err, np.repeat(full[:, 1:2], y.shape[1], axis=1)
    const_v = full[:, 1:2] + (full[:, 1:2] - full[:, :1]) * 60 * steps
    preds = {"model": model, "hold": hold, "constant_velocity": const_v}
    out = {"approach1": ev_metrics.approach1(y, model, names), "approach2": ev_metrics.approach2(y, model, names),
           "baselines": {k: {"approach1": ev_metrics.approach1(y, v, names),
                             "approach2": ev_metrics.approach2(y, v, names)} for k, v in preds.items() if k != "model"},
           "horizons": horizon_report(y, preds, names, 1 / 60, [1, 15, 60, 120]),
           "meta": {"n": 16, "context_len": 200, "horizon": 120, "y_names": names,
                    "physics": {"mode": "regression"}, "baseline_notes": {}}}
    return out


def test_the_overview_leads_with_error_by_horizon_and_shows_no_mean_over_per_window_fits(tmp_path):
    """Issue 61 §5: the demo's page led with "A1 R² −69.956 ± 221.973, A1 FIT −71.5 ± 275.6" in red for a model
    20 times better than hold, ruled by a channel at rest; then came the curves of a decoder the prediction does
    not read."""
    root = tmp_path / "runs"
    run = make_run(root, "demo")
    metrics = scored_metrics()
    assert metrics["approach1"]["mean"]["fit"]["mean"] < -50  # the paper's mean: what the page led with before
    (run / "eval" / "heldout" / "metrics.json").write_text(json.dumps(metrics))
    page = Path(build_report(str(root), str(tmp_path / "report.html"))).read_text()
    overview = page.split("<h2>Overview</h2>")[1].split("<h2>")[0]
    heads = re.findall(r"<th[^>]*>([^<]*)</th>", overview)
    assert heads[:3] == ["run", "evaluation", "joints RMS [mrad] at step 1 / 0.25 s / 1 s"]  # what it leads with
    sub = heads[heads.index("normalization") + 1:]  # the second header row: under the groups
    assert sub[:3] == ["model", "hold", "constant velocity"]
    assert sub[3:7] == ["R² median (A1)", "FIT median (A1)", "R² pooled (A2)", "FIT pooled (A2)"]
    row = re.findall(r"<tr>(.*?)</tr>", overview.split("</thead>")[1])[0]
    cells = re.findall(r"<td[^>]*>([^<]*)</td>", row)
    median_fit = float(cells[6 + 1])  # after run, evaluation (with its link), three horizon cells and R² median
    assert median_fit > 80 and "±" not in row  # medians over the windows where each channel moves, no means
    assert 'style="background:rgb(204, 235, 204)"' in row  # the model beats hold and constant velocity
    # The resting channel is marked where its scores are, greyed, and left out of the row over channels.
    evaluation = page.split("<h4>Evaluation")[1]
    assert "quiet in 12 of 16 windows" in evaluation and '<tr class="quiet"><td class="name">ee_qz' in evaluation
    assert evaluation.index("RMS error by horizon") < evaluation.index("A1 FIT median")  # error by horizon first
    # The curves follow the predictions and say whose they are.
    assert page.index("<h4>Evaluation") < page.index('<h2 id="curves">Training curves</h2>')
    assert "demo: its evaluations were predicted by the hybrid (regression), which does not read the decoder" in page


@pytest.mark.parametrize("layout, message, hint", [
    ("missing", "does not exist", "robomorph.fit"),
    ("empty", "no runs found", "robomorph.fit"),
    ("one run", "looks like a single run", "pass the folder that holds the runs"),
])
def test_missing_or_empty_runs_dir_is_a_clear_error(tmp_path, capsys, layout, message, hint):
    runs = tmp_path / "runs"
    if layout != "missing":
        runs.mkdir()
    if layout == "one run":
        (runs / "config.yaml").write_text(CONFIG.format(name="runs"))
    with pytest.raises(ReportError, match=message):
        build_report(str(runs), str(tmp_path / "r.html"))
    assert main([str(runs)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err and hint in err
    assert not (tmp_path / "r.html").exists() and not (tmp_path / "report.html").exists()


def test_cli_writes_next_to_runs_dir_by_default(tmp_path):
    root = tmp_path / "results" / "runs"
    make_run(root, "alpha", logs=False)
    done = subprocess.run([sys.executable, "-m", "robomorph.report", str(root), "--title", "My <title>"],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert done.returncode == 0, done.stderr
    out = tmp_path / "results" / "report.html"
    assert done.stdout.strip() == str(out)
    page = out.read_text()
    assert "<title>My &lt;title&gt;</title>" in page
    assert "No run has a logs/metrics.csv" in page
    assert [p.name for p in out.parent.iterdir() if p.is_file()] == ["report.html"]  # no temp file left


# --- rendering in headless Chromium over the DevTools protocol ---------------------------

class DevTools:
    """Just enough of a WebSocket client (RFC 6455) to speak the DevTools protocol, stdlib only."""

    def __init__(self, url: str, timeout: float = 30.0):
        parts = urllib.parse.urlsplit(url)
        self.sock = socket.create_connection((parts.hostname, parts.port), timeout=timeout)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(f"GET {parts.path} HTTP/1.1\r\nHost: {parts.netloc}\r\nUpgrade: websocket\r\n"
                          f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n".encode())
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self._fill()
        head, self.buf = self.buf.split(b"\r\n\r\n", 1)
        assert head.startswith(b"HTTP/1.1 101"), head.decode(errors="replace")
        self.last_id, self.events = 0, []

    def _fill(self) -> None:
        chunk = self.sock.recv(1 << 16)
        if not chunk:
            raise ConnectionError("DevTools closed the connection")
        self.buf += chunk

    def _read(self, n: int) -> bytes:
        while len(self.buf) < n:
            self._fill()
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def _send(self, payload: bytes, opcode: int = 0x1) -> None:
        n, mask = len(payload), os.urandom(4)  # clients must mask every frame
        size = bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack("!H", n) if n < 65536 \
            else bytes([0x80 | 127]) + struct.pack("!Q", n)
        masked = (np.frombuffer(payload, np.uint8) ^ np.resize(np.frombuffer(mask, np.uint8), n)).tobytes()
        self.sock.sendall(bytes([0x80 | opcode]) + size + mask + masked)

    def _message(self) -> dict:
        data = b""
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            n = struct.unpack("!H", self._read(2))[0] if n == 126 else struct.unpack("!Q", self._read(8))[0] if n == 127 else n
            payload, opcode = self._read(n), b0 & 0x0F  # server frames are never masked
            if opcode == 0x8:
                raise ConnectionError("DevTools closed the connection")
            if opcode == 0x9:
                self._send(payload, 0xA)
            elif opcode in (0x0, 0x1, 0x2):
                data += payload
                if b0 & 0x80:
                    return json.loads(data)

    def call(self, method: str, **params) -> dict:
        self.last_id += 1
        self._send(json.dumps({"id": self.last_id, "method": method, "params": params}).encode())
        while True:
            msg = self._message()
            if msg.get("id") == self.last_id:
                if "error" in msg:
                    raise RuntimeError(f"{method} failed: {msg['error']}")
                return msg["result"]
            self.events.append(msg)

    def wait_for(self, method: str) -> None:
        while not any(e.get("method") == method for e in self.events):
            self.events.append(self._message())

    def errors(self) -> list[str]:
        """Uncaught exceptions, console.error calls and error-level log entries seen so far."""
        out = []
        for e in self.events:
            method, p = e.get("method"), e.get("params", {})
            if method == "Runtime.exceptionThrown":
                d = p["exceptionDetails"]
                out.append(d.get("exception", {}).get("description") or d.get("text", "exception"))
            elif method == "Runtime.consoleAPICalled" and p.get("type") == "error":
                out.append(" ".join(str(a.get("value", a.get("description"))) for a in p.get("args", [])))
            elif method == "Log.entryAdded" and p["entry"].get("level") == "error":
                out.append(p["entry"].get("text", ""))
        return out


def _http(port: int, path: str, method: str = "GET") -> bytes:
    opener = urllib.request.build_opener(urllib.request.ProxyHandler({}))  # never via an http_proxy
    with opener.open(urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method), timeout=10) as r:
        return r.read()


@pytest.fixture(scope="session")
def chromium() -> str:
    """Path of Debian's chromium, installed by tools/ensure_chromium.sh when missing."""
    if not shutil.which("chromium"):
        done = subprocess.run(["bash", str(ROOT / "tools" / "ensure_chromium.sh")], capture_output=True, text=True, timeout=600)
        if not shutil.which("chromium"):
            pytest.fail("chromium is needed for the report rendering test and could not be installed; run "
                        f"`bash tools/ensure_chromium.sh` (as root or with sudo). Its output:\n{done.stdout}{done.stderr}")
    return shutil.which("chromium")


@pytest.fixture(scope="module")
def browser(chromium, tmp_path_factory):
    """A headless Chromium with remote debugging on a free port; yields the port."""
    profile = tmp_path_factory.mktemp("chromium-profile")
    log = open(profile.parent / "chromium.log", "w+")
    proc = subprocess.Popen(
        [chromium, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
         "--no-default-browser-check", "--disable-extensions", "--disable-background-networking",
         "--remote-debugging-port=0", f"--user-data-dir={profile}", "--window-size=1280,1400", "about:blank"],
        stdout=subprocess.DEVNULL, stderr=log)
    port_file, deadline = profile / "DevToolsActivePort", time.monotonic() + 60
    while not (port_file.is_file() and port_file.read_text().strip()):
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            log.seek(0)
            pytest.fail(f"chromium did not open its DevTools port:\n{log.read()[-3000:]}")
        time.sleep(0.1)
    yield int(port_file.read_text().split()[0])
    proc.terminate()
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.close()


def render(port: int, page: Path) -> dict:
    """Loads ``page`` in a fresh tab and returns its errors, table/image counts and a screenshot."""
    target = json.loads(_http(port, "/json/new?about:blank", method="PUT"))
    tab = DevTools(target["webSocketDebuggerUrl"])
    try:
        for domain in ("Page", "Runtime", "Log"):
            tab.call(f"{domain}.enable")
        tab.call("Page.navigate", url=page.resolve().as_uri())
        tab.wait_for("Page.loadEventFired")
        probe = ("new Promise(done => requestAnimationFrame(() => setTimeout(() => done(JSON.stringify({"
                 "tables: document.querySelectorAll('table').length, images: document.images.length,"
                 "broken: Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0)).length})), 100)))")
        found = tab.call("Runtime.evaluate", expression=probe, awaitPromise=True, returnByValue=True)
        found = json.loads(found["result"]["value"])
        shot = base64.b64decode(tab.call("Page.captureScreenshot", format="png")["data"])
        return {**found, "errors": tab.errors(), "screenshot": shot}
    finally:
        tab.sock.close()
        _http(port, f"/json/close/{target['id']}")


def is_blank(png: bytes) -> bool:
    """True when a screenshot is one flat colour (or nearly: fewer than 8 distinct colours)."""
    from matplotlib.image import imread

    pixels = imread(io.BytesIO(png), format="png")[..., :3].reshape(-1, 3)
    return len(np.unique(pixels, axis=0)) < 8 or float(pixels.std()) < 1e-3


def test_report_renders_in_chromium(browser, report):
    seen = render(browser, report)
    assert seen["errors"] == []
    assert seen["tables"] >= 2  # overview + alpha's per-channel table
    assert seen["images"] == 2 and seen["broken"] == 0
    assert not is_blank(seen["screenshot"])


def test_browser_checks_catch_a_broken_page(browser, tmp_path):
    """Negative control: the same checks must fail on a page that throws, logs an error or breaks an image."""
    bad = tmp_path / "bad.html"
    bad.write_text('<!DOCTYPE html><html><body><img src="data:image/png;base64,AAAA">'
                   '<script>console.error("logged"); throw new Error("x")</script></body></html>')
    seen = render(browser, bad)
    assert any("Error: x" in e for e in seen["errors"]) and any("logged" in e for e in seen["errors"])
    assert seen["broken"] == 1 and seen["tables"] == 0
    blank = tmp_path / "blank.html"
    blank.write_text("<!DOCTYPE html><html><body></body></html>")
    assert is_blank(render(browser, blank)["screenshot"])
