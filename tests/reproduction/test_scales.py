"""The reproduction's scales: documented sizes, budgets scaled, invalid scales refused."""

import dataclasses

import pytest

from robomorph.reproduction.scales import SCALES


def test_scales_hold_the_documented_sizes():
    paper = SCALES["paper"]
    assert (paper.d_model, paper.n_head, paper.depths, paper.patch, paper.batch_size) == (192, 12, (10, 12, 16), 1, 16)
    assert (paper.context_len, paper.horizon, paper.steps) == (200, 800, 1000) and paper.scratch_steps == 183_600
    small = SCALES["small"].scaled(0.5, scratch_ratio=2.0)
    assert small.train_steps == SCALES["small"].train_steps // 2 and small.scratch_steps == 2 * small.finetune_steps
    with pytest.raises(ValueError, match="multiple of patch"):
        dataclasses.replace(SCALES["small"], context_len=205)


@pytest.mark.parametrize("change, message", [({"depths": (1, 2)}, "three positive"),
                                             ({"horizon": 900}, "exceeds"),
                                             ({"n_head": 5}, "divisible by n_head"),
                                             ({"train_steps": 0}, "train_steps must be >= 1"),
                                             ({"val_fraction": 1.0}, "val_fraction")])
def test_invalid_scales_name_the_field(change, message):
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(SCALES["ci"], **change)


def test_budgets_follow_the_scaling_and_never_reach_zero():
    tiny = SCALES["ci"].scaled(0.01)
    assert (tiny.train_steps, tiny.pretrain_steps, tiny.finetune_steps, tiny.scratch_steps) == (1, 1, 1, 1)
    assert tiny.budgets()["table1_steps_per_depth"] == 1 and SCALES["ci"].transfer_depth == 2
    with pytest.raises(ValueError, match="steps_factor"):
        SCALES["ci"].scaled(0)
