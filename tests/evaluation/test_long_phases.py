"""No phase of a long command is silent (evaluate and its sweeps, calibrate, identified physics, control's
episodes, reproduce's data): with a fake slow step (each call several times the progress interval), lines
reach stderr while every slow call runs, and never 15 s apart."""

import re
import shutil
import sys
import time

import pytest

from robomorph.inference.predictor import Predictor
from tests.conftest import CKPT_CONTEXT as C
from tests.conftest import CKPT_HORIZON as H
from tests.core.test_progress import stamped

SLOW = 0.8  # seconds per model call: four lines' worth at the test's 0.2 s interval
LIMIT = 15.0  # the bound on silence


@pytest.fixture
def slow_model(monkeypatch):
    """Every Predictor.simulate sleeps SLOW seconds, then predicts for real; yields the calls' (start, end)."""
    real, spans = Predictor.simulate, []

    def simulate(self, *args, **kwargs):
        start = time.monotonic()
        time.sleep(SLOW)
        out = real(self, *args, **kwargs)
        spans.append((start, time.monotonic()))
        return out

    monkeypatch.setattr(Predictor, "simulate", simulate)
    return spans


def _check(stderr, spans, start: float, end: float, phases: tuple[str, ...]) -> None:
    assert spans, "the fake slow step never ran"
    assert max(stderr.gaps(start, end)) < LIMIT
    for a, b in spans:  # each slow call was reported while it ran, not only after it
        assert any(a <= t <= b for t, _ in stderr.lines), (a, b, stderr.lines)
    texts = [line for _, line in stderr.lines]
    for phase in phases:  # the heartbeat's lines, and a count with its rate once an item is done
        mine = [t for t in texts if t.startswith(f"{phase}: ")]
        assert any(" elapsed" in t for t in mine), (phase, texts)
        assert any(re.search(r"\d+/\d+ \w+(, | in ).*([\d.]+ \w+/s|[\d.]+ s/\w+)", t) for t in mine), (phase, texts)


def test_evaluate_and_its_sweeps_report_progress(tiny_checkpoint, simulated_store, slow_model, tmp_path,
                                                 monkeypatch):
    from robomorph.evaluate import main

    data = simulated_store(robots=6, steps=C + H, seed=2)
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["--ckpt", tiny_checkpoint, "--data", data, "--out", str(tmp_path / "ev"), "--n", "4",
                 "--baselines", "hold", "--plot-trajectories", "1", "--sweep-horizon", "30,60",
                 "--sweep-context", "10,30"]) == 0
    _check(stderr, slow_model, start, time.monotonic(), ("model", "horizon sweep", "context sweep"))


def test_calibrate_reports_progress(gaussian, tmp_path, slow_model, monkeypatch):
    from robomorph.calibrate import main

    _, best = gaussian
    ckpt = str(tmp_path / "model.ckpt")
    shutil.copy(best, ckpt)
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["--ckpt", ckpt, "--method", "coverage"]) == 0



@pytest.fixture(scope="module")
def gaussian(simulated_store, tmp_path_factory):
    """best.ckpt of a tiny Gaussian-head model (calibrate needs a std) and its store."""
    from robomorph.training.fitting import fit
    from tests.conftest import tiny_fit_args

    store = simulated_store(robots=24, steps=C + H, seed=1)
    result = fit(tiny_fit_args(store, tmp_path_factory.mktemp("runs"), "gauss",
                               model={"anchor": True, "gaussian": True, "loss": "nll"}))
    return store, result.best_ckpt


def test_the_sweeps_predict_means_alone_and_score_as_with_the_std(gaussian, monkeypatch):
    """A sweep reports R² and FIT only: it asks no std (a hybrid's costs many simulations), and its scores
    are those of the same windows scored with the std."""
    from robomorph.evaluation.evaluator import sweep_context, sweep_horizon
    from robomorph.evaluation.scoring import score_windows
    from robomorph.evaluation.windows import load_window

    store, best = gaussian
    pred = Predictor.from_checkpoint(best, device="cpu")
    w = load_window(store, C, H, 4, pred.data_info, pred.n_u, pred.n_y)
    real, asked = Predictor.simulate, []

    def simulate(self, *args, **kwargs):
        asked.append(bool(kwargs.get("return_std")))
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Predictor, "simulate", simulate)
    rows = sweep_horizon(pred, w, [30, 60], {}, 64) + sweep_context(pred, w, [10, 30], 64)
    assert asked and not any(asked)
    asked.clear()
    with_std = score_windows(pred, w.cut(horizon=30), (), [])
    assert any(asked) and with_std.std is not None  # the default scores the std, so the comparison means something
    assert rows[0]["model"] == with_std.summary()


def _slowed(monkeypatch, owner, name: str) -> list:
    """``owner.name`` sleeps SLOW seconds before doing its real work; returns the calls' (start, end)."""
    real, spans = getattr(owner, name), []

    def slow(*args, **kwargs):
        start = time.monotonic()
        time.sleep(SLOW)
        out = real(*args, **kwargs)
        spans.append((start, time.monotonic()))
        return out

    monkeypatch.setattr(owner, name, slow)
    return spans


def test_identified_physics_reports_progress(tiny_checkpoint, simulated_store, tmp_path, monkeypatch):
    """The per-window parameter fit of ``identified_physics`` (seconds a window): a line per window while each runs."""
    from robomorph.evaluate import main
    from robomorph.evaluation.identified import IdentifiedPhysics

    data = simulated_store(robots=6, steps=C + H, seed=2)
    spans = _slowed(monkeypatch, IdentifiedPhysics, "__call__")
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["--ckpt", tiny_checkpoint, "--data", data, "--out", str(tmp_path / "ev"), "--n", "3",
                 "--baselines", "hold,identified_physics", "--plot-trajectories", "1"]) == 0
    # The phase up to its last window (the plots written after it are evaluate's, checked above).
    _check(stderr, spans, start, spans[-1][1], ("identified physics",))


def test_control_episodes_report_progress(tmp_path, monkeypatch):
    """``robomorph control``: a line per few seconds with the episodes done, while each episode runs."""
    from robomorph.cli import main
    from robomorph.control import cli as control_cli

    spans = _slowed(monkeypatch, control_cli, "_job")
    monkeypatch.setattr(sys, "argv", list(sys.argv))  # robomorph.cli.main sets it for the door it runs
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["control", "--controllers", "osc", "--robots", "2", "--duration", "0.5", "--workers", "1",
                 "--out", str(tmp_path / "ctl")]) == 0
    _check(stderr, spans, start, time.monotonic(), ("control circle",))


def test_reproduce_generates_in_a_log_with_progress_lines(tmp_path, monkeypatch):
    """``robomorph reproduce`` in a log (stderr not a terminal): its stores' generation reports lines (it was
    silent there, the bar being for terminals only), and its trainings ask for fit's step lines."""
    from robomorph.data import generation
    from robomorph.reproduction import pipeline
    from robomorph.reproduction.scales import SCALES

    spans = _slowed(monkeypatch, generation, "_simulate")
    plan = pipeline.Plan(SCALES["ci"], str(tmp_path / "work"), str(tmp_path / "out"), "test", workers=1)
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    path = pipeline.prepared_store(plan, "ms_test0", "table1")
    _check(stderr, spans, start, time.monotonic(), ("generate multisine",))
    assert path.endswith("ms_test0.zarr")
    args = pipeline.base_args(plan, 1, [path], "r", 10)
    assert args["trainer"]["enable_progress_bar"] is True  # fit's StepBar: a bar on a terminal, lines in a log


def test_the_demos_summaries_and_plots_report_progress(tmp_path, monkeypatch):
    """make demo draws each showcase store (a minute on a loaded machine): lines while the drawing runs."""
    from robomorph.reproduction import demo

    monkeypatch.setattr(demo, "TASKS", ("multisine",))  # one store is enough to see the phase
    spans = _slowed(monkeypatch, demo, "plot")
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    demo.make_data(str(tmp_path), robots=2, steps=40, workers=1)
    _check(stderr, spans, start, time.monotonic(), ("multisine: summary and plots",))
    assert stderr.lines[-1][1].startswith("multisine: summary and plots: 1/1 store in ")  # done, counted


def test_blend_reports_progress(tiny_checkpoint, slow_model, tmp_path, monkeypatch):
    """``robomorph calibrate --blend`` (a total-torque model's physics/decoder blend): its predictions report."""
    from robomorph.calibrate import main

    ckpt = str(tmp_path / "model.ckpt")
    shutil.copy(tiny_checkpoint, ckpt)
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["--ckpt", ckpt, "--blend"]) == 0
    _check(stderr, slow_model, start, time.monotonic(), ("decoder",))  # the decoder predictions the blend weighs


def test_evaluates_plots_report_progress(tiny_checkpoint, simulated_store, tmp_path, monkeypatch):
    """Writing evaluate's figures (tens of seconds on a loaded machine): its own phase, lines while it runs."""
    from robomorph.evaluate import main
    from robomorph.evaluation import plots

    data = simulated_store(robots=6, steps=C + H, seed=2)
    spans = _slowed(monkeypatch, plots, "write_all")
    stderr = stamped(monkeypatch, "0.2")
    start = time.monotonic()
    assert main(["--ckpt", tiny_checkpoint, "--data", data, "--out", str(tmp_path / "ev"), "--n", "3",
                 "--baselines", "hold", "--plot-trajectories", "1"]) == 0
    assert len(spans) == 1
    assert max(stderr.gaps(start, time.monotonic())) < LIMIT
    (a, b), = spans
    during = [line for t, line in stderr.lines if a <= t <= b]
    assert any(line.startswith("plots: ") and " elapsed" in line for line in during), stderr.lines
