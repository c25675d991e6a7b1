"""HybridSettings: one frozen, validated object for every knob of the hybrid; the Predictor's configure and its
deprecated ``physics_*`` aliases; the key that names a setting and the calibration key."""

from __future__ import annotations

import dataclasses

import pytest

from robomorph.inference.predictor import PredictionError
from robomorph.inference.settings import HybridSettings, SettingsError


def test_the_settings_are_frozen_and_replace_validates_the_whole():
    s = HybridSettings(mode="regression")
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.members = 1
    assert s.replace(members=1).members == 1 and s.members == 9
    with pytest.raises(SettingsError, match="no hybrid setting membres; the settings are mode, samples"):
        s.replace(membres=1)
    for name, value in (("members", 0), ("samples", True), ("workers", 2.0), ("substeps", 0), ("points", "sigma"),
                        ("candidates", "approximate"), ("observer", 1), ("seed", -1), ("mode", "bogus"),
                        ("smoother", {"q_std": 1.0})):
        with pytest.raises(SettingsError, match=name):
            s.replace(**{name: value})
    assert issubclass(SettingsError, PredictionError)


@pytest.mark.parametrize("key", ["regression", "regression+obs+springs+debias", "refined@1~1/2+obs+tangent",
                                 "none", "smoothed/8", "fused~3"])
def test_a_key_reads_back_to_the_same_settings(key):
    s = HybridSettings.from_key(key)
    assert s.key == key
    assert HybridSettings.from_key(s.key) == s


def test_a_key_names_every_switch_it_turns_on_and_keeps_the_rest_of_its_base():
    base = HybridSettings(mode="regression", observer=True, debias=True, samples=4, seed=3)
    s = HybridSettings.from_key("refined@2+springs", base)
    assert (s.mode, s.iterations, s.members, s.substeps) == ("refined", 2, 9, None)
    assert (s.observer, s.springs, s.debias, s.candidates) == (False, True, False, "exact")
    assert (s.samples, s.seed) == (4, 3)  # not named by a key: the base's
    with pytest.raises(SettingsError, match="flags after"):
        HybridSettings.from_key("regression+obs+fast")
    with pytest.raises(SettingsError, match="whole numbers"):
        HybridSettings.from_key("regression@two")
    with pytest.raises(SettingsError, match="mode 'regresion'"):
        HybridSettings.from_key("regresion")


def test_in_effect_turns_off_what_does_not_apply_and_keys_the_calibration():
    s = HybridSettings(mode="regression", observer=True, springs=True, debias=True)
    assert s.in_effect("command").calibration_key == "regression+obs+springs+debias"
    assert s.in_effect("total").calibration_key == "regression"  # the observer and the regression's switches: commands
    assert s.replace(mode="fused").in_effect("command").calibration_key == "fused+obs"  # the head's prior: no switches
    assert s.in_effect("command", "nominal_model").calibration_key == "regression+obs+springs"  # measured worse there
    assert s.replace(mode="none").in_effect("command").calibration_key == "none"


def test_the_record_gives_the_defaults():
    assert HybridSettings.of_record(None, "command").mode == "none"
    record = {"observer": True, "springs": True}  # a record written before the debiasing
    command = HybridSettings.of_record(record, "command")
    assert (command.mode, command.observer, command.springs, command.debias) == ("regression", True, True, False)
    assert HybridSettings.of_record(record, "total").mode == "none"
    assert HybridSettings.of_record(record, "total", blend=object()).mode == "blend"


def test_configure_replaces_the_predictors_settings_and_the_old_names_warn():
    from robomorph import Predictor

    p = Predictor.from_arm("panda")
    assert (p.settings.mode, p.settings.observer, p.settings.springs, p.settings.debias) == ("regression", True, True,
                                                                                            True)
    kept = p.settings
    assert p.configure(members=1, iterations=2) is p and p.settings.members == 1 and kept.members == 9
    p.configure(HybridSettings.from_key("refined~1", p.settings))
    assert p.settings.mode == "refined" and not p.settings.observer
    with pytest.warns(DeprecationWarning, match=r"physics_members is deprecated.*configure\(members=\.\.\.\)"):
        p.physics_members = 3
    assert p.settings.members == 3
    with pytest.warns(DeprecationWarning, match="settings.mode"):
        assert p.physics_mode == "refined"


@pytest.mark.parametrize("switch", ["observer", "springs", "debias", "offsets", "coulomb", "payload", "denoise"])
def test_a_calibration_fitted_with_a_switch_on_is_stored_where_those_settings_look_for_it(switch):
    """What calibrate records of the settings (their mode and switches) keys the calibration as the settings
    key their lookup: one builder of the key for both, whatever switch is on."""
    from robomorph.inference.calibration import SPREAD_SWITCHES, StdCalibration, calibration_key

    s = HybridSettings(mode="regression").replace(**{switch: True})
    source = {"physics_mode": s.mode, "offset": "start", **{name: getattr(s, name) for _, name in SPREAD_SWITCHES}}
    cal = StdCalibration(knots=(1,), scale=((1.0,),), source=source)
    assert calibration_key(cal) == s.calibration_key != HybridSettings(mode="regression").calibration_key
