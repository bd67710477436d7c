"""Tiny data sets in the real layouts (Micro-GPS, HD Ground, CSV, plain folder), written by the tests."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from gtsweep.datasets.geometry import similarity_pose
from gtsweep.datasets.synthetic import render_view

VIEW = (48, 64)  # (h, w)


def floor(seed: int = 0, side: int = 400) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.uniform(0, 255, (side // 8, side // 8)).astype(np.float32)
    return cv2.resize(small, (side, side), interpolation=cv2.INTER_CUBIC)


def trajectory(n: int = 10) -> list[np.ndarray]:
    """Poses along a line and back, so that consecutive frames overlap and far-apart frames meet again."""
    xs = [100 + 20 * i for i in range(n // 2)] + [100 + 20 * (n // 2 - 1 - i) + 6 for i in range(n - n // 2)]
    return [similarity_pose(x, 150 + 2 * i, 3.0 * i) for i, x in enumerate(xs)]


def write_views(folder: Path, names: list[str], poses: list[np.ndarray]) -> None:
    ground = floor()
    for name, pose in zip(names, poses):
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(path), render_view(ground, pose, VIEW))


def pose_text(pose: np.ndarray) -> str:
    return " ".join(f"{v:.10g}" for v in np.asarray(pose).ravel())


def microgps(root: Path, texture: str = "carpet", n: int = 10) -> Path:
    """``root/<texture>/database.txt`` (path line, 9-value pose line), .pgm images and a ``.test`` list."""
    folder = root / texture
    names = [f"database/frame{i:06d}.pgm" for i in range(n)]
    poses = trajectory(n)
    write_views(folder, names, poses)
    lines = [line for name, pose in zip(names, poses) for line in (name, pose_text(pose))]
    (folder / "database.txt").write_text("\n".join(lines) + "\n")
    write_views(folder, ["sequence_normal/frame00000001-1481226409333457.pgm"], [poses[0]])
    (folder / "sequence_normal.test").write_text("sequence_normal/frame00000001-1481226409333457.pgm\n")
    return folder / "database.txt"


def hdground(root: Path, texture: str = "office_carpet", n: int = 10) -> tuple[Path, Path]:
    """Two pose files: image and pose on one line, and on alternating lines (one pose marked invalid)."""
    folder = root / texture
    names = [f"{texture}/seq{i // 5}/HDG1_t001_s0001_i{i:07d}.png" for i in range(n)]
    poses = trajectory(n)
    write_views(root, names, poses)
    same_line = [f"{name} {pose_text(pose[:2].ravel())} 0 0 1" for name, pose in zip(names[:5], poses[:5])]
    alternating = [line for name, pose in zip(names[5:], poses[5:])
                   for line in (name, f"{pose_text(pose[:2].ravel())} 0 0 1")]
    alternating[-1] = "* " + alternating[-1]  # the data set marks this pose as invalid
    first, second = folder / "seq0.txt", folder / "seq1.txt"
    first.write_text("\n".join(same_line) + "\n")
    second.write_text("\n".join(alternating) + "\n")
    return first, second


def csv_poses(root: Path, n: int = 10) -> Path:
    """``poses.csv`` with a header ``image,x,y,theta,scale`` next to its images."""
    names = [f"img{i:03d}.png" for i in range(n)]
    poses = trajectory(n)
    write_views(root, names, poses)
    rows = ["image,x,y,theta,scale"] + [
        f"{name},{pose[0, 2]:.10g},{pose[1, 2]:.10g},{np.degrees(np.arctan2(pose[0, 1], pose[0, 0])):.10g},1"
        for name, pose in zip(names, poses)]
    (root / "poses.csv").write_text("\n".join(rows) + "\n")
    return root / "poses.csv"


def image_folder(root: Path, textures=("asphalt", "wood"), n: int = 4) -> Path:
    for t, texture in enumerate(textures):
        for i in range(n):
            cv2.imwrite(str(_mkdir(root / texture) / f"{i:02d}.png"), floor(seed=10 * t + i, side=96)[:48, :64]
                        .astype(np.uint8))
    return root


def _mkdir(path: Path) -> Path:
    path.mkdir(parents=True, exist_ok=True)
    return path


def transfer_error(reference: np.ndarray, test: np.ndarray, H: np.ndarray) -> tuple[float, int]:
    """Mean |test(p) - reference(H p)| over test pixels p whose image H p lies inside the reference (bilinear),
    and how many pixels that is."""
    h, w = test.shape
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    mapped = H @ np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)])
    mx, my = (mapped[:2] / mapped[2]).reshape(2, h, w).astype(np.float32)
    inside = (mx >= 1) & (mx <= reference.shape[1] - 2) & (my >= 1) & (my <= reference.shape[0] - 2)
    warped = cv2.remap(reference.astype(np.float32), mx, my, cv2.INTER_LINEAR)
    if not inside.any():
        return float("nan"), 0
    return float(np.abs(warped - test.astype(np.float32))[inside].mean()), int(inside.sum())


SHIFT_2PX = np.array([[1, 0, 2.0], [0, 1, 0], [0, 0, 1]])


#: A data set of one's own in miniature: (h, w) of its views and the floors they are cut from.
OWN_VIEW = (240, 320)
OWN_FLOORS = {"asphalt": "coarse_asphalt", "carpet": "carpet"}


def own_path(per_texture: int = 12) -> list[tuple[float, float, float]]:
    """(x, y, theta) of the image's pixel (0, 0), theta in degrees: a path of ``per_texture // 2`` views along x,
    then revisits of the same stretch at another heading (the CSV's convention, ``similarity_pose``)."""
    half = per_texture // 2
    path = [(300.0 + 60 * i, 300.0 + 4 * i, 30.0 + 5 * i) for i in range(half)]
    back = [(600.0 - 60 * i, 520.0 + 4 * i, 120.0 + 5 * i) for i in range(per_texture - half)]
    return path + back


def own_csv(root: Path, per_texture: int = 12, written=lambda x, y, theta: (x, y, theta)) -> Path:
    """``poses.csv`` (``image,x,y,theta``) and PNG views of two textures rendered by the embedded renderer from
    floors of :mod:`gtsweep.datasets.floors`. ``written(x, y, theta)`` gives the values the CSV holds (another
    convention than the images': e.g. theta negated)."""
    from gtsweep.datasets.floors import make_floor

    for t, (texture, kind) in enumerate(sorted(OWN_FLOORS.items())):
        ground = make_floor(kind, np.random.default_rng(t), (1000, 1000), 6.25)
        for i, (x, y, theta) in enumerate(own_path(per_texture)):
            cv2.imwrite(str(_mkdir(root / texture) / f"{i:03d}.png"),
                        render_view(ground, similarity_pose(x, y, theta), OWN_VIEW))
    return own_csv_rows(root, per_texture, written)


def own_csv_rows(root: Path, per_texture: int = 12, written=lambda x, y, theta: (x, y, theta),
                 name: str = "poses.csv") -> Path:
    """The CSV (``name``) of :func:`own_csv` alone, beside its images (written before)."""
    rows = ["image,x,y,theta"] + [f"{texture}/{i:03d}.png," + ",".join(f"{v:.6g}" for v in written(*values))
                                  for texture in sorted(OWN_FLOORS) for i, values in enumerate(own_path(per_texture))]
    (root / name).write_text("\n".join(rows) + "\n")
    return root / name
