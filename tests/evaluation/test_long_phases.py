"""No phase of evaluate or calibrate is silent: with a fake slow step in the model (each call several times
the progress interval), lines reach stderr while every slow call runs, and never 15 s apart."""

import re
import shutil
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
                 "--baselines", "hold", "--samples", "1", "--sweep-horizon", "30,60",
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
    _check(stderr, slow_model, start, time.monotonic(), ("model",))


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
