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
