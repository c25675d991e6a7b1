"""robomorph priors: the hybrid's prediction over a store's windows, its record, resuming, and the residual
Predictor's own prior equal to the stored one."""

from __future__ import annotations

import numpy as np
import pytest

from robomorph.data.priors import PriorError
from robomorph.data.store import open_store
from robomorph.evaluation import priors
from robomorph.evaluation.priors import PriorRequest, write_priors

CONTEXT, HORIZON = 60, 20


@pytest.fixture(scope="module")
def source(simulated_store):
    return simulated_store(robots=3, steps=CONTEXT + HORIZON + 10, seed=4)


@pytest.mark.slow
def test_priors_are_the_hybrids_prediction_from_the_context_and_commands(source, tmp_path):
    from robomorph.inference.predictor import Predictor
    from robomorph.inference.residual import hybrid_of

    out = str(tmp_path / "p.zarr")
    record = write_priors(PriorRequest(source, out, CONTEXT, HORIZON, (0, 10), batch=4))
    ds, src = open_store(out), open_store(source)
    assert ds.n == 6 and ds.steps == CONTEXT + HORIZON and ds.attrs["prior"] == record
    assert record["settings"].endswith("+coulomb+payload+denoise") and record["offsets"] == [0, 10]
    assert record["source_seed"] == src.attrs["seed"] and record["inputs"] == "command"
    np.testing.assert_array_equal(ds.read("source_row"), [0, 1, 2, 0, 1, 2])
    np.testing.assert_array_equal(ds.read("offset"), [0, 0, 0, 10, 10, 10])
    # A robot's windows are one recording: the DataModule's splits keep them together.
    np.testing.assert_array_equal(ds.read("recording_index"), ds.read("source_row"))
    u_cmd, y = src.read("u_cmd"), src.read("y")
    np.testing.assert_array_equal(ds.read("u_cmd")[3], u_cmd[0, 10:10 + CONTEXT + HORIZON])
    np.testing.assert_array_equal(ds.read("y")[4], y[1, 10:10 + CONTEXT + HORIZON])
    # The very prediction of the hybrid the record names, on the window's context and commands.
    hybrid, _ = hybrid_of(Predictor, record["recipe"], record["fields"], record["arm"])
    w = u_cmd[:, :CONTEXT + HORIZON], y[:, :CONTEXT + HORIZON]
    expected = hybrid.simulate(w[0][:, :CONTEXT], w[1][:, :CONTEXT], w[0][:, CONTEXT:], at_rest=True)
    np.testing.assert_allclose(ds.read("prior")[:3], expected, rtol=0, atol=1e-6)


@pytest.mark.slow
def test_an_interrupted_store_is_resumed_to_the_same_rows(source, tmp_path, monkeypatch):
    whole = str(tmp_path / "whole.zarr")
    write_priors(PriorRequest(source, whole, CONTEXT, HORIZON, (0,), batch=1))
    part = str(tmp_path / "part.zarr")
    calls = []
    real = priors._batch  # every batch's priors, the first one's (computed before the store exists) included

    def stop_after_one(*args):
        if calls:
            raise KeyboardInterrupt
        calls.append(1)
        return real(*args)

    monkeypatch.setattr(priors, "_batch", stop_after_one)
    with pytest.raises(KeyboardInterrupt):
        write_priors(PriorRequest(source, part, CONTEXT, HORIZON, (0,), batch=1))
    assert open_store(part, allow_incomplete=True).n == 1
    monkeypatch.setattr(priors, "_batch", real)
    with pytest.raises(PriorError, match="begun with other arguments"):
        write_priors(PriorRequest(source, part, CONTEXT, HORIZON + 1, (0,), batch=1))
    write_priors(PriorRequest(source, part, CONTEXT, HORIZON, (0,), batch=1))
    np.testing.assert_array_equal(open_store(part).read("prior"), open_store(whole).read("prior"))
    # Complete and of the same request: left as it is.
    monkeypatch.setattr(priors, "_batch", stop_after_one)
    write_priors(PriorRequest(source, part, CONTEXT, HORIZON, (0,), batch=1))


def test_requests_that_cannot_work_are_refused(source, tmp_path):
    out = str(tmp_path / "p.zarr")
    with pytest.raises(PriorError, match="exceed the store's T=90 steps"):
        write_priors(PriorRequest(source, out, CONTEXT, HORIZON, (20,)))
    for kw, phrase in (({"offsets": ()}, "--offsets"), ({"offsets": (0, 0)}, "distinct"), ({"horizon": 0}, "--horizon"),
                       ({"n": 0}, "--n")):
        with pytest.raises(PriorError, match=phrase):
            PriorRequest(source, out, **{"context": CONTEXT, "horizon": HORIZON, **kw})
