"""The names of a reproduction's runs and evaluations: what the pipeline trains and scores into
(:mod:`robomorph.reproduction.pipeline`) and what :mod:`robomorph.reproduction.collect` reads back.

Names carry the budget, so a run of another ``--steps-factor`` is another run; the pipeline's
``Plan.run_name`` adds the normalization and input formulation.
"""

from __future__ import annotations

from robomorph.core.names import REGIMES
from robomorph.reproduction.improved import IMPROVED
from robomorph.reproduction.scales import Scale
from robomorph.reproduction.tables import REGIME_TITLES

# The evaluation folders (``<run>/eval/<name>``) of Table 2's spiral test and of the context figure's sweeps.
SPIRAL_EVAL = "spiral_test"
SWEEPS_EVAL = "test0-sweeps"


def table1_run(scale: Scale, depth: int) -> str:
    """Table 1's model of ``depth`` layers (also the context figure's, at the middle depth)."""
    return f"table1-L{depth}-s{scale.train_steps}"


def improved_run(scale: Scale) -> str:
    """Table 1's improved model, at the middle depth."""
    return f"table1-{IMPROVED}-L{scale.transfer_depth}-s{scale.train_steps}"


def table2_budgets(scale: Scale) -> dict[str, int]:
    """Steps trained on the spiral in each of Table 2's regimes (zero-shot: none)."""
    return {"zero_shot": 0, "finetune": scale.finetune_steps, "scratch": scale.scratch_steps}


def pretrain_run(scale: Scale) -> str:
    """Table 2's model pre-trained on the mixture (scored zero-shot, and the fine-tuning's start)."""
    return f"table2-pretrain-L{scale.transfer_depth}-s{scale.pretrain_steps}"


def table2_run(scale: Scale, regime: str) -> str:
    """The run whose ``spiral_test`` evaluation is ``regime``'s column of Table 2."""
    steps = table2_budgets(scale)[regime]
    return pretrain_run(scale) if regime == "zero_shot" else f"table2-{regime}-L{scale.transfer_depth}-s{steps}"


def table2_titles(scale: Scale) -> dict[str, str]:
    """Table 2's column titles, with the steps of the regimes that train."""
    steps = table2_budgets(scale)
    return {g: REGIME_TITLES[g] + (f" ({steps[g]} steps)" if steps[g] else "") for g in REGIMES}
