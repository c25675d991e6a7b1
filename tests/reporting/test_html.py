"""The page's building blocks: FIT colours, escaping, metric text, the channel table."""

import numpy as np
import pytest

from robomorph.evaluation import metrics
from robomorph.reporting.html import best_baseline, channel_table, esc, fit_colour, fmt, mean_stat, page


@pytest.mark.parametrize(
    "fit, colour",
    [(100.0, "rgb(166, 241, 166)"), (90.0, "rgb(166, 241, 166)"), (89.99, "rgb(200, 247, 200)"),
     (80.0, "rgb(200, 247, 200)"), (79.99, "rgb(255, 255, 128)"), (60.0, "rgb(255, 255, 128)"),
     (59.99, "rgb(255, 210, 128)"), (30.0, "rgb(255, 210, 128)"), (29.99, "rgb(255, 179, 179)"),
     (-250.0, "rgb(255, 179, 179)"), (None, None), (float("nan"), None)],
)
def test_fit_colour_follows_the_paper_convention(fit, colour):
    assert fit_colour(fit) == colour


def test_text_is_escaped_and_numbers_formatted():
    assert esc('<a href="x">') == "&lt;a href=&quot;x&quot;&gt;"
    assert (fmt(0.91234, 0.01, "r2"), fmt(87.25, None, "fit"), fmt(0.012345, None, "rmse"), fmt(None, None, "r2")) == \
        ("0.912 ± 0.010", "87.2", "0.0123", "—")


def _metrics():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(3, 20, 2))
    model, hold = y + 0.1 * rng.normal(size=y.shape), np.repeat(y[:, :1], 20, axis=1)
    names = ["a", "<b>"]
    return {"approach1": metrics.approach1(y, model, names), "approach2": metrics.approach2(y, model, names),
            "baselines": {"hold": {"approach1": metrics.approach1(y, hold, names)},
                          "true_physics": {"approach1": metrics.approach1(y, y, names)}}}


def test_the_channel_table_has_every_channel_and_the_mean_escaped():
    m = _metrics()
    text = channel_table(m)
    assert text.count("<tr>") == 2 + 2 and '<tr class="mean">' in text  # two header rows, two channels
    assert "&lt;b&gt;" in text and "<b>" not in text
    # without a stored mean the average of the channels stands in; with nothing, nothing
    assert mean_stat({"approach2": {"channels": {"a": {"r2": 0.5}, "b": {"r2": 0.7}}}}, "approach2", "r2") == \
        (pytest.approx(0.6), None)
    assert mean_stat(m["baselines"]["hold"], "approach2", "r2") == (None, None)
    assert mean_stat(m, "approach1", "fit")[0] == pytest.approx(m["approach1"]["mean"]["fit"]["mean"])


def test_the_true_physics_ceiling_never_counts_as_the_best_baseline():
    name, fit = best_baseline(_metrics())
    assert name == "hold" and fit < 100


def test_a_page_is_a_whole_html_document_with_an_escaped_title():
    text = page("a < b", "<p>x</p>")
    assert text.lstrip().lower().startswith("<!doctype html>") and "<title>a &lt; b</title>" in text
