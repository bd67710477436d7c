"""Numba signatures shared by gtsweep's compiled loops (SURF's window sampler, MSD's saliency).

A compiled loop is given an explicit signature, so it compiles once (or loads from Numba's cache) rather than per
call. Numba dispatches on an array's writeable flag, and Ray's object store hands images to its workers read-only,
so every image argument is declared both ways.
"""
from __future__ import annotations


def image_types(numba) -> tuple:
    """A 2-D C-contiguous uint8 image, writable and read-only: one signature each."""
    t = numba.types
    return t.uint8[:, ::1], t.Array(t.uint8, 2, "C", readonly=True)


def signatures(numba, *rest) -> list:
    """``void(image, *rest)`` for each of :func:`image_types`."""
    return [numba.types.void(image, *rest) for image in image_types(numba)]
