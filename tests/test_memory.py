"""Tests of gtsweep.core.memory (peak resident memory of a process tree)."""
import subprocess
import sys
import time

import pytest

from gtsweep.core.memory import PeakMemory, tree_rss

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def test_a_child_holding_200_mib_counts_in_the_tree_not_in_the_driver():
    child = subprocess.Popen([sys.executable, "-c", "import time; b = bytearray(200 * 2**20); b[::4096] = b'x' * "
                              "len(b[::4096]); print(flush=True); time.sleep(30)"], stdout=subprocess.PIPE)
    try:
        child.stdout.readline()  # the memory is touched
        with PeakMemory(interval=0.05) as memory:
            time.sleep(0.2)
        tree = tree_rss(memory.pid)
        assert child.pid in tree and tree[child.pid] >= 200 * 2**20
        assert memory.total >= memory.driver + 200 * 2**20 and memory.driver < memory.total
        assert memory.workers == 0 and "whole process tree" in memory.line()
    finally:
        child.kill()
        child.wait()


def test_a_busy_child_s_cpu_seconds_count_as_the_tree_s_not_the_driver_s():
    import os

    from gtsweep.core.memory import cpu_split, tree_cpu

    before = tree_cpu(os.getpid())
    child = subprocess.Popen([sys.executable, "-c", "import time\nend = time.process_time() + 0.6\n"
                              "while time.process_time() < end: pass\nprint(flush=True)\ntime.sleep(30)"],
                             stdout=subprocess.PIPE)
    try:
        child.stdout.readline()  # 0.6 s of CPU spent
        after = tree_cpu(os.getpid())
        split = cpu_split(before, after, os.getpid())
        assert 0.6 <= after[child.pid] < 2.0 and split["ray"] >= 0.6  # a child that is not a Ray worker
        assert split["workers"] == 0.0 and 0.0 <= split["driver"] < split["ray"]
    finally:
        child.kill()
        child.wait()
