"""The compiled loops' shared compile step: compiled for writable and read-only images, or None (the NumPy path)
where it is forced, or Numba cannot compile (a warning naming the loop)."""
import logging

import numpy as np
import pytest

from gtsweep.stages.numba_types import compile_or_none

pytest.importorskip("numba")


def _fill(image, out):
    out[0] = image[0, 0] + image[-1, -1]


def _not_compilable(image, out):
    out[0] = {"a": image}  # a dict of arrays into a float32 slot: no Numba type for it


def _rest(types):
    return (types.float32[::1],)


def test_a_loop_compiles_for_writable_and_read_only_images():
    loop = compile_or_none(_fill, "GTSWEEP_TEST_KERNEL", "the test loop", _rest)
    image = np.arange(12, dtype=np.uint8).reshape(3, 4)
    for given in (image, image.copy()):
        given.flags.writeable = given is not image
        out = np.zeros(1, np.float32)
        loop(given, out)
        assert out[0] == 11.0


def test_the_numpy_path_forced_or_a_failed_compile_gives_none(monkeypatch, caplog):
    monkeypatch.setenv("GTSWEEP_TEST_KERNEL", "numpy")
    assert compile_or_none(_fill, "GTSWEEP_TEST_KERNEL", "the test loop", _rest) is None
    monkeypatch.delenv("GTSWEEP_TEST_KERNEL")
    with caplog.at_level(logging.WARNING):
        assert compile_or_none(_not_compilable, "GTSWEEP_TEST_KERNEL", "the broken loop", _rest) is None
    assert "Numba could not compile the broken loop" in caplog.text and "NumPy path" in caplog.text
