import pytest

from robomorph.core.errors import MissingInputError, RoboMorphError, UsageError, run_command


def test_bad_input_becomes_one_line_and_exit_code_2(capsys):
    def bad():
        raise UsageError("--n must be >= 1,\n  got 0")

    assert run_command(bad) == 2
    assert capsys.readouterr().err == "error: --n must be >= 1, got 0\n"


def test_other_errors_still_raise_and_success_passes_through():
    def bug():
        raise KeyError("a bug, not bad input")

    with pytest.raises(KeyError):
        run_command(bug)
    assert run_command(lambda: None) == 0 and run_command(lambda: 3) == 3


def test_error_classes_keep_their_builtin_kinds():
    # Callers that caught the built-in kinds before still catch them.
    assert issubclass(MissingInputError, FileNotFoundError) and issubclass(UsageError, ValueError)
    assert issubclass(MissingInputError, RoboMorphError)
