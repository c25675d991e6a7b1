import subprocess
import sys
import typing

import pytest

from robomorph.core import names
from robomorph.core.errors import RoboMorphError


def test_core_and_transfer_checks_import_no_torch():
    # The reason names live in core: configuration checks must not pull in the training stack.
    code = ("import sys, robomorph.core.names, robomorph.core.rundir, robomorph.core.overrides, "
            "robomorph.core.atomic, robomorph.core.locks, robomorph.core.config, robomorph.training.transfer; "
            "print(sorted(m for m in ('torch', 'lightning', 'matplotlib') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]"


def test_the_code_uses_the_names():
    from robomorph.evaluation.metrics import METRICS
    from robomorph.sim.recipe import Recipe
    from robomorph.training.module import MetaModule

    assert tuple(METRICS) == names.METRICS  # the evaluation writes them in this order
    hints = typing.get_type_hints(MetaModule.__init__)
    assert typing.get_args(hints["freeze"]) == names.FREEZE_MODES and typing.get_args(hints["loss"]) == names.LOSSES
    assert typing.get_args(typing.get_type_hints(Recipe)["gravity_compensation"]) == names.GRAVITY_MODES
    assert set(names.CURVES) <= {names.TRAIN_LOSS, names.VAL_LOSS, names.VAL_R2, names.VAL_FIT}
    assert names.TASKS == names.OPEN_LOOP_TASKS + names.OSC_TASKS


@pytest.mark.parametrize("bad", ["", ".", "..", "../../x", "/abs/path", "a/b", "a\\b", ".hidden", "x\0y"])
def test_a_name_that_is_not_plain_is_refused_in_one_line(bad):
    with pytest.raises(RoboMorphError, match="--run .* is not a plain name") as err:
        names.check_plain_name(bad, "--run")
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("good", ["ms", "ms-small_2", "run-20250101-120000", "a.b", "t0001"])
def test_plain_names_pass_unchanged(good):
    assert names.check_plain_name(good, "--run") == good
