"""Parsing the pose and image-list files of real ground-texture data sets.

Micro-GPS ``database.txt`` (Zhang et al. ICRA 2019, ``zhangaigh/micro-gps-cpp``): per image a line with the
relative image path, then a line with the 9 floats of the row-major 3x3 pose (image -> map).
HD Ground ``*.txt`` (Schmid et al. ICRA 2022): image path and pose "a b c d e f 0 0 1" on one line or on
alternating lines; a pose starting with ``*`` is marked incorrect by the data set and is left out.
``*.test`` files list image paths without poses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np

from gtsweep.core.errors import BadInput


class Problems:
    """Bad-input policy: raise ``BadInput("<where>: <reason>")``, or with ``skip_bad`` record it and go on."""

    def __init__(self, skip_bad: bool):
        self.skip_bad = bool(skip_bad)
        self.skipped: list[str] = []

    def report(self, where: str, reason: str) -> None:
        message = f"{where}: {reason}"
        if not self.skip_bad:
            raise BadInput(message)
        self.skipped.append(message)


@dataclass(frozen=True)
class Entry:
    """An image listed in a file: resolved path, pose (or None), "file:line" and its recording session."""

    path: Path
    listed_as: str
    pose: np.ndarray | None
    where: str
    session: str
    order: int


def numbered_lines(file: Path) -> Iterator[tuple[int, str]]:
    """(line number, stripped text) of the non-empty lines of a text file; BadInput if unreadable."""
    try:
        text = file.read_text(encoding="utf-8", errors="replace")
    except OSError as error:
        raise BadInput(f"cannot read {file}: {error.strerror or error}") from None
    for number, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            yield number, line.strip()


def floats(tokens: Sequence[str]) -> list[float] | None:
    """The tokens as floats, or None if any is not a number (``nan`` and ``inf`` are numbers: :func:`finite`)."""
    try:
        return [float(t) for t in tokens]
    except ValueError:
        return None


def finite(values: Sequence[float] | None) -> bool:
    """Every value is a finite number (a pose with ``nan`` or ``inf`` is a bad item, not a pose)."""
    return values is not None and all(math.isfinite(v) for v in values)


def pose_from_values(values: list[float], where: str, problems: Problems) -> np.ndarray | None:
    """A 3x3 pose from 9 row-major values; reports a wrong count or a non-affine/degenerate matrix."""
    if len(values) != 9:
        problems.report(where, f"pose needs 9 values, found {len(values)}")
        return None
    if not finite(values):
        problems.report(where, "pose values must be finite numbers (found nan or inf)")
        return None
    pose = np.array(values, dtype=np.float64).reshape(3, 3)
    if not np.allclose(pose[2], (0.0, 0.0, 1.0), atol=1e-6):
        problems.report(where, "pose is not an affine matrix (its last row must be 0 0 1)")
        return None
    if abs(np.linalg.det(pose[:2, :2])) < 1e-9:
        problems.report(where, "pose is degenerate (zero determinant)")
        return None
    return pose


def resolve_image(listed: str, bases: Sequence[Path]) -> Path | None:
    """The first existing ``base / listed`` (or ``listed`` itself if absolute), else None."""
    candidate = Path(listed)
    if candidate.is_absolute():
        return candidate if candidate.is_file() else None
    for base in bases:
        if (base / candidate).is_file():
            return base / candidate
    return None


class _Collector:
    """Turns (path, pose) records into entries, checking that each image exists."""

    def __init__(self, file: Path, bases: Sequence[Path], problems: Problems):
        self.file, self.bases, self.problems = file, bases, problems
        self.entries: list[Entry] = []

    def add(self, listed: str, line: int, pose: np.ndarray | None) -> None:
        where = f"{self.file}:{line}"
        path = resolve_image(listed, self.bases)
        if path is None:
            self.problems.report(where, f"image {listed} does not exist")
            return
        self.entries.append(Entry(path, listed, pose, where, str(self.file), len(self.entries)))


def read_microgps_database(file: Path, problems: Problems) -> list[Entry]:
    """Entries of a Micro-GPS ``database.txt`` (path line, then a line of 9 pose values)."""
    collect = _Collector(file, [file.parent], problems)
    pending: tuple[int, str] | None = None
    for number, text in numbered_lines(file):
        values = floats(text.split())
        if pending is None:
            if values is not None:
                problems.report(f"{file}:{number}", "expected an image path, found numbers")
            else:
                pending = (number, text)
            continue
        path_line, listed = pending
        if values is None:
            problems.report(f"{file}:{number}", f"expected the 9 pose values of image {listed}, found '{text}'")
            pending = (number, text)
            continue
        pending = None
        pose = pose_from_values(values, f"{file}:{number}", problems)
        if pose is not None:
            collect.add(listed, path_line, pose)
    if pending is not None:
        problems.report(f"{file}:{pending[0]}", f"image {pending[1]} has no pose line")
    return collect.entries


def read_hdground_poses(file: Path, root: Path, problems: Problems) -> tuple[list[Entry], list[str]]:
    """Entries of an HD Ground ``*.txt`` pose file, and the "file:line" of poses the data set marks invalid."""
    collect = _Collector(file, [file.parent, root], problems)
    invalid: list[str] = []
    pending: tuple[int, str] | None = None

    def take_pose(line: int, tokens: list[str], listed: str) -> None:
        where = f"{file}:{line}"
        if tokens[0].startswith("*"):
            invalid.append(f"{where}: pose of {listed} marked invalid by the data set")
            return
        values = floats(tokens)
        if values is None:
            problems.report(where, f"pose of image {listed} is not numeric: '{' '.join(tokens)}'")
            return
        pose = pose_from_values(values, where, problems)
        if pose is not None:
            collect.add(listed, line, pose)

    for number, text in numbered_lines(file):
        tokens = text.split()
        is_pose = tokens[0].startswith("*") or floats(tokens[:1]) is not None
        if is_pose:
            if pending is None:
                problems.report(f"{file}:{number}", "pose line without an image path before it")
            else:
                take_pose(number, tokens, pending[1])
                pending = None
            continue
        if pending is not None:
            problems.report(f"{file}:{pending[0]}", f"image {pending[1]} has no pose")
        pending = None
        if len(tokens) > 1:
            take_pose(number, tokens[1:], tokens[0])
        else:
            pending = (number, tokens[0])
    if pending is not None:
        problems.report(f"{file}:{pending[0]}", f"image {pending[1]} has no pose")
    return collect.entries, invalid


def read_image_list(file: Path, bases: Sequence[Path], problems: Problems) -> list[Entry]:
    """Entries (without poses) of a ``*.test`` file: one image path per line."""
    collect = _Collector(file, bases, problems)
    for number, text in numbered_lines(file):
        tokens = text.split()
        # "path" alone, or "path <numbers...>" (extra columns are ignored); a path may contain spaces
        listed = tokens[0] if floats(tokens[1:]) is not None else text
        collect.add(listed, number, None)
    return collect.entries
