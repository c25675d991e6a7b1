"""The package's vocabulary, defined once: log keys, metric names, tasks and modes.

Torch-free, so that configuration checks (transfer regimes, sweep spaces, recipes) and
readers of results (the dashboard) use the same names as the training code without
importing it.
"""

from __future__ import annotations

from robomorph.core.errors import UsageError

# Log keys, namespaced as the lightning-hydra-template does (``logs/metrics.csv`` columns).
TRAIN_LOSS, VAL_LOSS, VAL_R2, VAL_FIT, LR = "train/loss", "val/loss", "val/r2", "val/fit", "lr"
TEST_LOSS, TEST_R2, TEST_FIT = "test/loss", "test/r2", "test/fit"
# The curves the dashboard draws against the step.
CURVES = (TRAIN_LOSS, VAL_LOSS, VAL_R2)

# Evaluation metrics, in the order the evaluation computes and writes them.
R2, RMSE, NRMSE, FIT = "r2", "rmse", "nrmse", "fit"
METRICS = (R2, RMSE, NRMSE, FIT)

# Training losses (on normalized outputs).
LOSSES = ("huber", "mse", "nll")  # nll: the Gaussian head's negative log-likelihood

# Tasks a recipe can generate: open-loop torque signals and OSC-tracked paths.
OPEN_LOOP_TASKS = ("multisine", "chirp")
OSC_TASKS = ("circle", "spiral")
TASKS = OPEN_LOOP_TASKS + OSC_TASKS

# How the simulated arm compensates gravity (see robomorph.sim.recipe.Recipe).
GRAVITY_MODES = ("true_model", "nominal_model", "none")

# How the model normalizes (see robomorph.data.statistics): statistics of the training split,
# or the paper's per-window statistics (which leak the query outputs' statistics).
NORMALIZATIONS = ("train_stats", "paper_window")

# What the black-box decoder's output is a correction to (--model.extrapolate): nothing (or the
# last context output with --model.anchor), or constant-velocity extrapolation from the last
# context sample (robomorph.inference.checkpoint.kinematic_anchor).
EXTRAPOLATIONS = ("none", "velocity")

# What the model reads as u (data.inputs): the total joint torque, or the command before the
# arm's gravity compensation (a store's u_cmd).
INPUTS = ("total", "command")
# How a training step runs (--model.compile, reproduce --compile): robomorph.training.compiling.
COMPILE_MODES = ("auto", "off", "default", "reduce-overhead", "max-autotune")

# How a model with a physics backbone predicts (robomorph.inference.hybrid), besides ``none`` (its decoder).
PHYSICS_MODES = ("learned", "regression", "fused", "refined", "blend", "smoothed")
# The hybrid's on/off switches that a checkpoint's physics record carries (robomorph.inference.settings.HybridSettings
# .of_record), which ``robomorph calibrate --NAME on|off`` sets before fitting.
RECORDED_SWITCHES = ("observer", "springs", "debias", "payload", "coulomb", "denoise")
# How a model trained today records the switches of its physics record (robomorph.training.module,
# robomorph.inference.catalogue): every one of :data:`RECORDED_SWITCHES` on. A record written
# before a switch existed lacks it and predicts as before (:meth:`HybridSettings.of_record`). The payload, the wider
# friction and the denoising since 2026-11-28: on the held-out Pandas of results/benchmarks/sensitivity.md the three
# together are within 4 % of the hybrid without them on clean data (2.78 against 2.80 mrad at 13.3 s), 2.6 times lower
# with 1e-4 rad of encoder noise (6.86 against 17.7), and on the `realistic` recipe 0.067 / 1.27 / 5.6 / 28 / 195 mrad
# at steps 1 / 15 / 60 / 300 / 800 against 0.132 / 5.0 / 31 / 330 / 422.
TODAYS_RECORD = {name: True for name in RECORDED_SWITCHES}

# Which parameters a fine-tuned model keeps fixed, and the transfer regimes of Table 2.
FREEZE_MODES = ("none", "encoder", "all_but_head")
REGIMES = ("zero_shot", "finetune", "scratch")


def check_plain_name(value: str, what: str) -> str:
    """Returns ``value`` when it is a plain name (one folder or file name); raises otherwise.

    Run and study names become folder names under ``--runs_dir``: a separator, ``.``/``..``
    or an absolute path would write elsewhere (``--run ../../x``) or make the runs folder
    itself a run (``--run .``). A leading dot is refused too: the writers' lock files are
    hidden names beside the folders they guard (:mod:`robomorph.core.locks`).

    Args:
        value: the name given.
        what: how the user gave it, for the message (``--run``, ``--study-name``, ``name:``).

    Raises:
        UsageError: ``value`` is empty, starts with ``.``, or holds ``/``, ``\\`` or a NUL.
    """
    if not isinstance(value, str) or not value or value.startswith(".") or any(c in value for c in "/\\\0"):
        raise UsageError(f"{what} {value!r} is not a plain name: give a name without '/' or '\\' "
                         "that does not start with '.' (it names a folder inside the runs folder)")
    return value
