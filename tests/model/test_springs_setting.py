"""The regression of the joints' springs as a checkpoint's setting (commands): on for new fits, off for records
that predate it, switched by ``calibrate --springs``, each setting with its own std calibrations."""

from __future__ import annotations

import numpy as np
import torch

from tests.conftest import CKPT_CONTEXT, CKPT_HORIZON
from tests.model.test_hybrid import _windows, command_store, hybrid_ckpt  # noqa: F401  (fixtures)


def test_new_fits_fit_the_springs_and_records_written_before_predict_as_they_did(hybrid_ckpt, command_store, tmp_path):
    """A new fit records the springs on; a record without the key (a checkpoint from before it) predicts, mean and
    std, exactly as the same model with them off, which differs from fitting them; the std then moves them too."""
    from robomorph.model.files import DATA_INFO_KEY
    from robomorph.model.predictor import Predictor

    ckpt = torch.load(hybrid_ckpt, weights_only=False, map_location="cpu")
    assert ckpt[DATA_INFO_KEY]["physics"]["springs"] is True
    del ckpt[DATA_INFO_KEY]["physics"]["springs"]
    old_path = str(tmp_path / "old.ckpt")
    torch.save(ckpt, old_path)
    uc, yc, uq, *_ = _windows(command_store, n=3)
    new, old = Predictor.from_checkpoint(hybrid_ckpt), Predictor.from_checkpoint(old_path)
    assert new.physics_springs is True and old.physics_springs is False
    fitted, fitted_std = new.simulate(uc, yc, uq, at_rest=True, return_std=True)
    assert len(new.hybrid()._cov_space[0]) == len(new.hybrid().backbone.index) + 7  # the std moves the springs
    new.physics_springs = False
    mean, std = new.simulate(uc, yc, uq, at_rest=True, return_std=True)
    old_mean, old_std = old.simulate(uc, yc, uq, at_rest=True, return_std=True)
    np.testing.assert_array_equal(old_mean, mean)
    np.testing.assert_array_equal(old_std, std)
    assert len(new.hybrid()._cov_space[0]) == len(new.hybrid().backbone.index)
    assert np.abs(fitted - mean).max() > 1e-7 and np.abs(fitted_std - std).max() > 1e-7


def test_calibrate_springs_records_the_setting_and_each_keeps_its_calibrations(hybrid_ckpt, simulated_store,
                                                                                tmp_path, capsys):
    """--springs off/on writes the setting into the checkpoint and fits that setting's calibration beside the
    other's; the Predictor applies the one of the setting it predicts with; evaluate's note names it."""
    from robomorph.calibrate import main
    from robomorph.model.predictor import Predictor

    out = str(tmp_path / "springs.ckpt")
    heldout = simulated_store(robots=4, steps=CKPT_CONTEXT + CKPT_HORIZON, seed=8)
    common = ["--data", heldout, "--n", "4", "--physics", "regression"]
    assert main(["--ckpt", hybrid_ckpt, "--out", out, *common, "--springs", "off"]) == 0
    off = Predictor.from_checkpoint(out)
    assert off.physics_springs is False and set(off.model.calibrations) == {"regression+obs"}
    assert "springs fitted" not in capsys.readouterr().out
    assert main(["--ckpt", out, *common, "--springs", "on"]) == 0
    assert "the springs fitted" in capsys.readouterr().out
    p = Predictor.from_checkpoint(out)
    cals = p.model.calibrations
    assert p.physics_springs is True and set(cals) == {"regression+obs", "regression+obs+springs"}
    assert p.calibration is cals["regression+obs+springs"]
    assert cals["regression+obs+springs"].scale != cals["regression+obs"].scale
    p.physics_springs = False
    assert p.calibration is cals["regression+obs"]
    p.physics_springs, p.physics_mode = True, "learned"  # the head's robot: no regression, no springs
    assert p.calibration is None
