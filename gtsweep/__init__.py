"""gtsweep: the ground-texture feature survey of Schmid, Simon and Mester (BMVC 2019) as a sweep tool.

``SURF_create`` is a drop-in for OpenCV's (OpenCV's own when the installed build has it, else a NumPy port of
OpenCV's surf.cpp); ``XFeat_create`` is the learned feature that runs on ``cv2.dnn``. Both are imported on first
use, so that ``import gtsweep`` (and the first instants of ``python -m gtsweep``, where Ctrl-C must be quiet) loads
no OpenCV.

Importing gtsweep first pins NumPy's and OpenBLAS's CPU paths, so that an AVX-512 machine renders views as an AVX2
machine does (:mod:`gtsweep.core.numeric_backends`; the few views known to differ still: docs/reproduction_run.md).
"""
import importlib

from gtsweep.core.numeric_backends import pin_this_process

pin_this_process()

__all__ = ["SURF_create", "XFeat_create"]
__version__ = "0.1.0"
_LAZY = {"SURF_create": "gtsweep.stages.surf", "XFeat_create": "gtsweep.stages.xfeat"}


def __getattr__(name: str):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'gtsweep' has no attribute {name!r}")
