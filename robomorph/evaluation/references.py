"""What an evaluation scores beside the model besides the fixed baselines: the ARX models
fitted on the model's training data (``arx_train``, ``accel_arx_train``) and other
checkpoints (``--compare``)."""

from __future__ import annotations

from robomorph.evaluation.baselines import BASELINES, CEILINGS, OPT_IN, TrainedAccelARX, TrainedARX
from robomorph.evaluation.windows import EvaluationError


def fit_arx_train(orders: tuple[int, int], train_blocks) -> TrainedARX:
    """``arx_train`` fitted on ``train_blocks()`` (see :func:`robomorph.evaluation.training_data.reader`)."""
    if train_blocks is None:
        raise ValueError("arx_train needs the training data: pass --arx-train-data")
    return TrainedARX(*orders).fit(train_blocks())


def fit_accel_arx_train(train_blocks) -> TrainedAccelARX:
    """``accel_arx_train`` fitted on ``train_blocks()``, as :func:`fit_arx_train`."""
    if train_blocks is None:
        raise ValueError("accel_arx_train needs the training data: pass --arx-train-data")
    return TrainedAccelARX().fit(train_blocks())


def load_other(name: str, ckpt: str, w, device: str | None):  # w: evaluation.windows.Window
    """Another checkpoint (``--compare name=ckpt``), checked against the evaluated windows."""
    from robomorph.inference.predictor import Predictor  # noqa: PLC0415

    if name in BASELINES + OPT_IN + CEILINGS + ("model",):
        raise EvaluationError(f"--compare {name}=...: {name!r} names a baseline; choose another name")
    other = Predictor.from_checkpoint(ckpt, device=device)
    info = other.data_info or {}
    if (info.get("u_names"), info.get("y_names")) != (w.u_names, w.y_names):
        raise EvaluationError(f"--compare {name}: {ckpt} was trained on other channels ({info.get('u_names')} -> "
                         f"{info.get('y_names')}) than the store's ({w.u_names} -> {w.y_names})")
    patch = int(other.patch)
    if w.context_len % patch:
        raise EvaluationError(f"--compare {name}: context {w.context_len} is not a multiple of its patch {patch}")
    return other
