"""Exclusive locks: a second holder is refused naming the first's pid; a dead holder's lock is free again."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from fabline.errors import FablineError
from fabline.locks import exclusive_lock, lock_path

HOLD = ("import sys, time\nfrom fabline.locks import exclusive_lock\n"
        "with exclusive_lock(sys.argv[1], 'the folder'):\n    print('held', flush=True)\n    time.sleep(60)\n")


def test_a_second_holder_is_refused_with_the_first_ones_pid_and_a_killed_holder_frees_it(tmp_path):
    lock = tmp_path / "job" / ".fabline.lock"
    holder = subprocess.Popen([sys.executable, "-c", HOLD, str(lock)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(FablineError, match=rf"the folder is in use by process {holder.pid} "):
            with exclusive_lock(lock, "the folder"):
                pass
    finally:
        holder.kill()
        holder.wait()
    with exclusive_lock(lock, "the folder"):  # SIGKILL released it; the stale file does not block
        assert lock.read_text().strip() == str(os.getpid())


def test_one_port_has_one_lock_whatever_path_names_it(tmp_path):
    device = tmp_path / "ttyUSB0"
    device.touch()
    alias = tmp_path / "by-id"
    alias.symlink_to(device)
    assert lock_path(str(alias)) == lock_path(str(device))
    assert lock_path("socket://127.0.0.1:5000") != lock_path("socket://127.0.0.1:5001")
