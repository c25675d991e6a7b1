"""The input formulations a store can hold and a model can be trained on.

``total``: the total joint torque (gravity compensation included), array ``u``; ``command``:
the command without the gravity compensation the arm adds, array ``u_cmd``. Torch-free: the
store, the DataModule, the Predictor and evaluation all check against these names.
"""

from __future__ import annotations

from robomorph.core.errors import RoboMorphError

INPUTS = ("total", "command")
INPUT_ARRAYS = {"total": "u", "command": "u_cmd"}
MEANING = {"total": "total joint torque, gravity compensation included",
           "command": "the command, without the gravity compensation the arm adds"}


class InputsError(RoboMorphError, ValueError):
    """A store or a model does not hold the input formulation asked for."""


def check_inputs(inputs: str) -> str:
    """``inputs`` if it names a formulation, else a :class:`InputsError` listing them."""
    if inputs not in INPUTS:
        raise InputsError(f"inputs must be one of {', '.join(INPUTS)} (total joint torque, or the command "
                          f"without the arm's gravity compensation), got {inputs!r}")
    return inputs


def check_model_inputs(trained: str, given: str | None) -> None:
    """Refuses torques of formulation ``given`` for a model trained on ``trained`` (None: unchecked)."""
    if given is not None and check_inputs(given) != trained:
        raise InputsError(
            f"the model was trained on inputs={trained} ({MEANING[trained]}) but was given "
            f"inputs={given} ({MEANING[given]}): feed it the {trained} array "
            f"({INPUT_ARRAYS[trained]}) or use a checkpoint trained with data.inputs={given}")
