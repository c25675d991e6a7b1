"""The observer's start velocity as a checkpoint's setting: on for new fits, off for records that
predate it, switched by ``calibrate --observer``, each setting with its own std calibrations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON
from tests.model.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def test_new_fits_observe_and_records_written_before_predict_as_they_did(hybrid_ckpt, command_store, tmp_path):
    """A new fit records the observer on; a record without the key (a checkpoint from before it)
    predicts exactly as the same model with the observer off, which differs from observing."""
    from robomorph.model.files import DATA_INFO_KEY
    from robomorph.model.predictor import Predictor

    ckpt = torch.load(hybrid_ckpt, weights_only=False, map_location="cpu")
    assert ckpt[DATA_INFO_KEY]["physics"]["observer"] is True
    del ckpt[DATA_INFO_KEY]["physics"]["observer"]
    old_path = str(tmp_path / "old.ckpt")
    torch.save(ckpt, old_path)
    uc, yc, uq, *_ = _windows(command_store, n=3)
    new, old = Predictor.from_checkpoint(hybrid_ckpt), Predictor.from_checkpoint(old_path)
    assert new.physics_observer is True and old.physics_observer is False
    observed = new.simulate(uc, yc, uq, at_rest=True)
    new.physics_observer = False
    np.testing.assert_array_equal(old.simulate(uc, yc, uq, at_rest=True), new.simulate(uc, yc, uq, at_rest=True))
    assert np.abs(observed - old.simulate(uc, yc, uq, at_rest=True)).max() > 1e-6


def test_calibrate_observer_records_the_setting_and_each_keeps_its_calibrations(hybrid_ckpt, simulated_store,
                                                                                 tmp_path, capsys):
    """--observer off/on writes the setting into the checkpoint and fits that setting's calibration
    beside the other's; the Predictor applies the one of the setting it predicts with; --remove
    --physics drops a mode's calibrations with and without the observer."""
    from robomorph.calibrate import main
    from robomorph.model.predictor import Predictor

    out = str(tmp_path / "obs.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=8)
    common = ["--data", heldout, "--n", "4", "--physics", "regression"]
    assert main(["--ckpt", hybrid_ckpt, "--out", out, *common, "--observer", "off"]) == 0
    off = Predictor.from_checkpoint(out)
    assert off.physics_observer is False and set(off.model.calibrations) == {"regression+springs"}
    assert "observer's start velocity" not in capsys.readouterr().out
    assert main(["--ckpt", out, *common, "--observer", "on"]) == 0
    assert "with the observer's start velocity" in capsys.readouterr().out
    p = Predictor.from_checkpoint(out)
    cals = p.model.calibrations
    assert p.physics_observer is True and set(cals) == {"regression+springs", "regression+obs+springs"}
    assert p.calibration is cals["regression+obs+springs"] and cals["regression+obs+springs"].scale != cals["regression+springs"].scale
    p.physics_observer = False
    assert p.calibration is cals["regression+springs"]
    assert main(["--ckpt", out, "--remove", "--physics", "regression"]) == 0
    assert Predictor.from_checkpoint(out).model.calibrations == {}


@pytest.mark.parametrize("option", [["--observer", "on"], ["--points", "columns"]])
def test_what_a_fit_is_fitted_on_is_not_a_removals_option(hybrid_ckpt, capsys, option):
    """--observer and --points set what a fit is fitted on: with --remove each is refused in one line, nothing
    written."""
    from robomorph.calibrate import main

    before = open(hybrid_ckpt, "rb").read()
    assert main(["--ckpt", hybrid_ckpt, *option, "--remove"]) == 2
    err = capsys.readouterr().err.strip()
    assert "drop --remove" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert open(hybrid_ckpt, "rb").read() == before
