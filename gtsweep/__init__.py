"""gtsweep: the ground-texture feature survey of Schmid, Simon and Mester (BMVC 2019) as a sweep tool.

``SURF_create`` is a drop-in for OpenCV's (OpenCV's own when the installed build has it, else a NumPy port of
OpenCV's surf.cpp); ``XFeat_create`` is the learned feature that runs on ``cv2.dnn``.
"""
from gtsweep.stages.surf import SURF_create
from gtsweep.stages.xfeat import XFeat_create

__all__ = ["SURF_create", "XFeat_create"]
__version__ = "0.1.0"
