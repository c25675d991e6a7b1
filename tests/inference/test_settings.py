"""A command hybrid's settings recorded in its checkpoint: the observer's start velocity, the regression of the joints'
springs and the regression's debiasing. Each is on for new fits, off for records that predate it, switched by
``calibrate --NAME on|off``, and each setting keeps its own std calibrations."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON
from tests.inference.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)

# setting -> (its part of a calibration key, what calibrate's report says of it)
SETTINGS = {"observer": ("+obs", "with the observer's start velocity"),
            "springs": ("+springs", "the springs fitted"),
            "debias": ("+debias", "its bias taken off"),
            "payload": ("+payload", "a payload fitted"),
            "coulomb": ("+coulomb", "friction beyond the box"),
            "denoise": ("+denoise", "the context's noise smoothed")}
# The calibration key of a new fit's default mode: every setting on.
KEY = "regression+obs+springs+debias+coulomb+payload+denoise"


@pytest.mark.parametrize("name", list(SETTINGS))
def test_new_fits_turn_it_on_and_records_written_before_predict_as_they_did(name, hybrid_ckpt, command_store,
                                                                           tmp_path):
    """A new fit records the setting on; a record without the key (a checkpoint from before it) predicts, mean and
    std, exactly as the same model with it off, which differs from it on."""
    from robomorph.model.files import DATA_INFO_KEY
    from robomorph.inference.predictor import Predictor

    ckpt = torch.load(hybrid_ckpt, weights_only=False, map_location="cpu")
    assert ckpt[DATA_INFO_KEY]["physics"][name] is True
    del ckpt[DATA_INFO_KEY]["physics"][name]
    old_path = str(tmp_path / "old.ckpt")
    torch.save(ckpt, old_path)
    uc, yc, uq, *_ = _windows(command_store, n=3)
    if name == "denoise":  # a noise-free context predicts as without it: give the joints an encoder's noise
        yc = yc.copy()
        yc[..., 7:] += np.random.default_rng(0).normal(0.0, 1e-4, yc[..., 7:].shape).astype(yc.dtype)
    new, old = Predictor.from_checkpoint(hybrid_ckpt), Predictor.from_checkpoint(old_path)
    assert getattr(new.settings, name) is True and getattr(old.settings, name) is False
    on, on_std = new.simulate(uc, yc, uq, at_rest=True, return_std=True)
    new.configure(**{name: False})
    mean, std = new.simulate(uc, yc, uq, at_rest=True, return_std=True)
    old_mean, old_std = old.simulate(uc, yc, uq, at_rest=True, return_std=True)
    np.testing.assert_array_equal(old_mean, mean)
    np.testing.assert_array_equal(old_std, std)
    assert np.abs(on - mean).max() > 1e-7 and np.abs(on_std - std).max() > 1e-7
    if name == "springs":  # the std moves the springs where they are fitted
        new.configure(**{name: True})
        new.simulate(uc, yc, uq, at_rest=True, return_std=True)
        assert len(new.hybrid()._cov_space[0]) == len(new.hybrid().backbone.index) + 7


@pytest.mark.parametrize("name", list(SETTINGS))
def test_calibrate_records_the_setting_and_each_keeps_its_calibrations(name, hybrid_ckpt, simulated_store, tmp_path,
                                                                       capsys):
    """--NAME off/on writes the setting into the checkpoint and fits that setting's calibration beside the other's;
    the Predictor applies the one of the setting it predicts with; --remove --physics drops the mode's all."""
    from robomorph.calibrate import main
    from robomorph.inference.predictor import Predictor

    part, said = SETTINGS[name]
    without = KEY.replace(part, "")
    out = str(tmp_path / f"{name}.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=8)
    common = ["--data", heldout, "--n", "4", "--physics", "regression"]
    assert main(["--ckpt", hybrid_ckpt, "--out", out, *common, f"--{name}", "off"]) == 0
    off = Predictor.from_checkpoint(out)
    assert getattr(off.settings, name) is False and set(off.model.calibrations) == {without}
    assert said not in capsys.readouterr().out
    assert main(["--ckpt", out, *common, f"--{name}", "on"]) == 0
    assert said in capsys.readouterr().out
    p = Predictor.from_checkpoint(out)
    cals = p.model.calibrations
    assert getattr(p.settings, name) is True and set(cals) == {without, KEY}
    assert p.calibration is cals[KEY]
    # The simulated store's contexts are noise-free, where the denoising predicts as without it (its own test
    # gives the joints noise); every other switch changes the spread.
    assert (cals[KEY].scale == cals[without].scale) == (name == "denoise")
    p.configure(**{name: False})
    assert p.calibration is cals[without]
    if name != "observer":  # the head's robot: no regression, so neither springs nor debiasing (nor calibration)
        p.configure(**{name: True})
        p.configure(mode="learned")
        assert p.calibration is None
    assert main(["--ckpt", out, "--remove", "--physics", "regression"]) == 0
    assert Predictor.from_checkpoint(out).model.calibrations == {}


@pytest.mark.parametrize("option", [["--observer", "on"], ["--springs", "off"], ["--debias", "on"],
                                    ["--points", "columns"]])
def test_what_a_fit_is_fitted_on_is_not_a_removals_option(hybrid_ckpt, capsys, option):
    """The settings and --points say what a fit is fitted on: with --remove each is refused in one line, nothing
    written."""
    from robomorph.calibrate import main

    before = open(hybrid_ckpt, "rb").read()
    assert main(["--ckpt", hybrid_ckpt, *option, "--remove"]) == 2
    err = capsys.readouterr().err.strip()
    assert "drop --remove" in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert open(hybrid_ckpt, "rb").read() == before
