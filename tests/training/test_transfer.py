import pytest

from robomorph.core.errors import RoboMorphError
from robomorph.training.transfer import FINETUNE_LR, REGIMES, regime_overrides


def test_regimes_give_the_documented_overrides():
    assert REGIMES == ("zero_shot", "finetune", "scratch")
    assert regime_overrides("zero_shot", "pre.ckpt", 100) is None
    assert regime_overrides("finetune", "pre.ckpt", 100) == {
        "model": {"init_ckpt": "pre.ckpt", "freeze": "none", "lr": FINETUNE_LR}, "trainer": {"max_steps": 100}}
    ft = regime_overrides("finetune", "pre.ckpt", 50, lr=1e-4, freeze="all_but_head")
    assert ft["model"] == {"init_ckpt": "pre.ckpt", "freeze": "all_but_head", "lr": 1e-4}
    # scratch never starts from the checkpoint and keeps the base lr unless one is given
    assert regime_overrides("scratch", "pre.ckpt", 200) == {
        "model": {"init_ckpt": None, "freeze": "none"}, "trainer": {"max_steps": 200}}
    assert regime_overrides("scratch", None, 200, lr=2e-3)["model"]["lr"] == 2e-3


@pytest.mark.parametrize("call, message", [
    (lambda: regime_overrides("fewshot", "a.ckpt", 10), "unknown transfer regime 'fewshot'"),
    (lambda: regime_overrides("finetune", None, 10), "finetune needs init_ckpt"),
    (lambda: regime_overrides("finetune", "a.ckpt", 0), "steps must be a positive integer"),
    (lambda: regime_overrides("finetune", "a.ckpt", 10, lr=0.0), "lr must be > 0"),
    (lambda: regime_overrides("finetune", "a.ckpt", 10, freeze="decoder"), "freeze must be one of"),
    (lambda: regime_overrides("scratch", None, 10, freeze="encoder"), "applies to finetune only"),
])
def test_bad_regime_arguments_are_refused(call, message):
    with pytest.raises(RoboMorphError, match=message):
        call()

