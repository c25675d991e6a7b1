"""The input formulations: known names, and a model refusing the other formulation."""

import pytest

from robomorph.core.inputs import INPUT_ARRAYS, INPUTS, InputsError, check_inputs, check_model_inputs


def test_each_formulation_names_its_array():
    assert INPUTS == ("total", "command") and INPUT_ARRAYS == {"total": "u", "command": "u_cmd"}
    assert check_inputs("command") == "command"
    with pytest.raises(InputsError, match="one of total, command"):
        check_inputs("torque")


def test_a_model_refuses_the_other_formulation_and_says_which_array_to_feed():
    check_model_inputs("total", None)  # unchecked
    check_model_inputs("total", "total")
    message = r"trained on inputs=command .* given inputs=total .* feed it the command array \(u_cmd\)"
    with pytest.raises(InputsError, match=message):
        check_model_inputs("command", "total")
