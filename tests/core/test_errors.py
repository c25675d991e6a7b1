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


def test_file_system_errors_become_one_line_others_still_raise(capsys):
    import errno
    import os

    def full():
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/data/out.zarr")

    def read_only():
        raise PermissionError(errno.EROFS, os.strerror(errno.EROFS), "/mnt/ro/eval")

    assert run_command(full) == 2
    assert capsys.readouterr().err == ("error: No space left on device: /data/out.zarr; the disk is full; free space "
                                       "or choose an output on another disk\n")
    assert run_command(read_only) == 2
    assert "Read-only file system: /mnt/ro/eval; the file system is mounted read-only" in capsys.readouterr().err

    def bug():
        raise OSError(errno.EBADF, os.strerror(errno.EBADF))  # a closed descriptor: the code's fault

    with pytest.raises(OSError):
        run_command(bug)
