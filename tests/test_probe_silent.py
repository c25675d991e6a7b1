"""The hostile probe of issue 61, section 2, defects 11 to 26: what was silently wrong, and what was
reported unclearly or late. Each test names its defect.

A Predictor's constructor and ``configure`` validate completely or change nothing; a command's refusal
is one ``error:`` line with exit code 2, no traceback, and nothing written; where the fix is a note
rather than a refusal, the note is in the output and in the result file.
"""

from __future__ import annotations

import numpy as np
import pytest

from robomorph import Predictor
from robomorph.core.config import ConfigError
from robomorph.inference.catalogue import LimitsError, NoNetworkError
from robomorph.inference.settings import SettingsError

C, H = 40, 20  # a context and a horizon of a few hundred milliseconds: from_arm predicts in well under a second


@pytest.fixture(scope="module")
def window(simulated_store):
    """One command window (u_ctx, y_ctx, u_query) of a simulated Panda."""
    from robomorph.data.store import open_store

    ds = open_store(simulated_store(robots=2, steps=C + H, seed=3))
    u, y = ds.read_inputs("command")[:1], ds.read("y")[:1]
    return u[:, :C], y[:, :C], u[:, C:]


# --- the Predictor: every constructor and configure validates completely, or changes nothing ---------------

def test_from_arm_refuses_a_sample_time_of_no_arm(window):
    """Defect 15: ``from_arm("panda", dt=1e9)`` was accepted and predicted poses up to 6.4e5."""
    for dt in (1e9, 2.0):
        with pytest.raises(ConfigError, match=rf"dt must be a sample time in seconds, > 0 and at most 1, got {dt}"):
            Predictor.from_arm("panda", dt=dt)
    assert Predictor.from_arm("panda", dt=0.01).data_info["dt"] == 0.01


def test_from_arm_refuses_torques_and_angles_in_the_wrong_units(window):
    """Defect 16: torques x1000 and joint angles in degrees returned plausible output."""
    uc, yc, uq = window
    pred = Predictor.from_arm("panda")
    with pytest.raises(LimitsError, match=r"^u_ctx reaches .* N m on 'cmd\d', .* times the panda's motor limit"):
        pred.simulate(uc * 1000, yc, uq, at_rest=True)
    with pytest.raises(LimitsError, match=r"^u_query reaches .* times the panda's motor limit .*give the torques in N m"):
        pred.simulate(uc, yc, uq * 1000, at_rest=True)
    degrees = np.concatenate([yc[..., :7], np.rad2deg(yc[..., 7:])], axis=-1)
    with pytest.raises(LimitsError, match=r"^y_ctx's joint angle 'q\d' reaches .* rad, outside the panda's joint "
                                          r"range .*radians \(not degrees\)"):
        pred.simulate(uc, degrees, uq, at_rest=True)
    mean = pred.simulate(uc, yc, uq, at_rest=True)  # the same window in its units: predicted
    assert mean.shape == (1, H, 14) and np.all(np.abs(mean) < 10)


def test_from_arm_refuses_a_robot_override_naming_another_arm():
    """Defect 17: ``from_arm("panda", robot="ur5e")`` built a UR5e predictor in silence."""
    with pytest.raises(NoNetworkError, match=r"^robot='ur5e' names another arm than 'panda'"):
        Predictor.from_arm("panda", robot="ur5e")
    assert Predictor.from_arm("panda", robot="panda").data_info["arm"] == "panda"  # the same arm twice: fine
    with pytest.raises(NoNetworkError, match=r"calibrated must be True or False, got 'yes'"):
        Predictor.from_arm("panda", calibrated="yes")


@pytest.mark.parametrize("changes, error, phrase", [
    ({"members": 10**9}, SettingsError, r"^members must be a whole number from 1 to 1024, got 1000000000"),
    ({"samples": 10**9}, SettingsError, r"^samples must be a whole number from 1 to"),
    ({"workers": 10**6}, SettingsError, r"^workers must be a whole number from 1 to 64"),
    ({"substeps": 10**9}, SettingsError, r"^substeps must be None or a whole number from 1 to 1000"),
    ({"iterations": 10**6}, SettingsError, r"^iterations must be a whole number from 1 to 100,"),
    ({"mode": "learned"}, NoNetworkError, r"^physics mode 'learned' reads a trained network"),
    ({"mode": "fused"}, NoNetworkError, r"^physics mode 'fused' reads a trained network"),
    ({"mode": "none"}, NoNetworkError, r"^physics mode 'none' reads a trained network"),
])
def test_configure_refuses_at_once_and_changes_nothing(window, changes, error, phrase):
    """Defect 20: ``configure(members=10**9)`` and, on from_arm, ``configure(mode='learned')`` passed, failed only
    at simulate, and stayed set, so that every later call failed."""
    pred = Predictor.from_arm("panda").configure(members=1, workers=1)
    before = pred.settings
    with pytest.raises(error, match=phrase):
        pred.configure(**changes)
    assert pred.settings == before
    (name, value), = changes.items()
    if hasattr(Predictor, f"physics_{name}"):  # the deprecated attribute goes through configure too
        with pytest.raises(error, match=phrase), pytest.warns(DeprecationWarning):
            setattr(pred, f"physics_{name}", value)
        assert pred.settings == before
    assert pred.simulate(*window, at_rest=True).shape == (1, H, 14)  # the next call predicts as before
