"""Exclusive locks on stores and run folders: one writer at a time, the holder named, and a
lock that frees itself when its process dies."""

import os
import signal
import socket
import subprocess
import sys

import pytest

from robomorph.core.errors import RoboMorphError
from robomorph.core.locks import LockedError, exclusive, exclusive_on, holder, lock_path

_HOLD = ("import sys, time\nfrom robomorph.core.locks import exclusive\n"
         "with exclusive(sys.argv[1]):\n    print('held', flush=True)\n    time.sleep(120)\n")


def test_a_second_writer_is_refused_with_the_holder_named(tmp_path):
    target = str(tmp_path / "ms.zarr")
    with exclusive(target):
        info = holder(target)
        assert info["pid"] == os.getpid() and info["host"] == socket.gethostname() and info["command"]
        with pytest.raises(LockedError) as err:
            with exclusive(target):
                pass
        msg = str(err.value)
        assert isinstance(err.value, RoboMorphError) and "\n" not in msg
        assert msg.startswith(f"{target} is being written by another process") and f"pid {os.getpid()}" in msg
        assert socket.gethostname() in msg
    assert holder(target) is None  # released: the sidecar goes, the next writer gets in
    with exclusive(target):
        pass
    assert not os.path.exists(target)  # the lock lives beside the target, never inside it
    assert os.path.dirname(lock_path(target)) == str(tmp_path)


def test_paths_to_one_target_share_one_lock(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    os.makedirs("data")
    os.symlink("data", "link")
    with exclusive("data/ms.zarr"):
        for other in ("data/ms.zarr/", "./data/../data/ms.zarr", str(tmp_path / "data" / "ms.zarr"), "link/ms.zarr"):
            with pytest.raises(LockedError):
                with exclusive(other):
                    pass


def test_the_decorator_locks_the_named_argument(tmp_path):
    calls = []

    @exclusive_on("out")
    def write(data, out, flag=False):
        calls.append(holder(out)["pid"])
        return out

    target = str(tmp_path / "x.zarr")
    assert write(1, target) == target and calls == [os.getpid()]
    with exclusive(target):
        with pytest.raises(LockedError):
            write(1, out=target)
    assert calls == [os.getpid()]


def test_a_lock_left_by_a_killed_process_frees_itself(tmp_path):
    target = str(tmp_path / "run")
    proc = subprocess.Popen([sys.executable, "-c", _HOLD, target], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        with pytest.raises(LockedError, match=f"pid {proc.pid} "):
            with exclusive(target):
                pass
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert holder(target)["pid"] == proc.pid  # the dead holder's note is still there ...
    with exclusive(target):  # ... but its lock died with it
        assert holder(target)["pid"] == os.getpid()
