"""Numba signatures shared by gtsweep's compiled loops (SURF's window sampler, MSD's saliency).

A compiled loop is given an explicit signature, so it compiles once (or loads from Numba's cache) rather than per
call. Numba dispatches on an array's writeable flag, and Ray's object store hands images to its workers read-only,
so every image argument is declared both ways.
"""
from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)


def image_types(numba) -> tuple:
    """A 2-D C-contiguous uint8 image, writable and read-only: one signature each."""
    t = numba.types
    return t.uint8[:, ::1], t.Array(t.uint8, 2, "C", readonly=True)


def signatures(numba, *rest) -> list:
    """``void(image, *rest)`` for each of :func:`image_types`."""
    return [numba.types.void(image, *rest) for image in image_types(numba)]


def compile_or_none(function, kernel_env: str, what: str, rest):
    """``function`` compiled by Numba as ``void(image, *rest(numba.types))`` for each of :func:`image_types`
    (compiled once per process, or read from Numba's cache), or None where the NumPy path is forced
    (``kernel_env=numpy``), Numba is not installed, or it cannot compile ``function`` (a warning naming ``what``)."""
    if os.environ.get(kernel_env, "").lower() == "numpy":
        return None
    try:
        import numba
    except ImportError:
        return None
    try:
        return numba.njit(signatures(numba, *rest(numba.types)), cache=True, nogil=True, fastmath=False,
                          error_model="numpy")(function)
    except Exception as e:  # noqa: BLE001 - any Numba/LLVM failure: the NumPy path gives the same numbers
        log.warning("Numba could not compile %s (%s); using the NumPy path", what,
                    str(e).splitlines()[0] if str(e) else type(e).__name__)
        return None
