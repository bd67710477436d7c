"""In-memory per-view rows of hand-chosen cells for the findings' verdict tests (no files, no detector runs)."""
from __future__ import annotations

import numpy as np
import pandas as pd

TEXTURES = 6


def cluster_ids(n: int, kind: str = "synthetic") -> list[tuple[str, str]]:
    """``n`` (texture, image) ids spread over 6 textures, image numbers 0, 1, 2 ... within each texture."""
    return [(f"t{i % TEXTURES}", f"t{i % TEXTURES}/{kind}/{i // TEXTURES:03d}") for i in range(n)]


def level(mean: float, clusters: int = 24, views: int = 9, noise: float = 0.002, seed: int = 0) -> np.ndarray:
    """Per-view values (clusters x views) around ``mean``."""
    return mean + np.random.default_rng(seed).normal(0.0, noise, size=(clusters, views))


def outcomes(successes: int, clusters: int) -> np.ndarray:
    """0/1 success of one view per pair (clusters x 1): the first ``successes`` of every 10 pairs succeed."""
    return ((np.arange(clusters) % 10) < successes).astype(float)[:, None]


class Fakes:
    """Cells of one preset: ``add`` a cell with per-view metric values; ``frame`` and ``views`` as the report
    reads them."""

    def __init__(self):
        self.rows, self.views = [], {}

    def add(self, detector, transform, values: dict[str, np.ndarray], selector="nms", descriptor=None,
            kind="synthetic", extra=None, by_count=None):
        key = "__".join([detector, selector, descriptor or "none", transform])
        first = next(iter(values.values()))
        clusters, views = first.shape
        ids = cluster_ids(clusters, kind)
        rows = []
        for c, (texture, image) in enumerate(ids):
            for v in range(views):
                row = {"view": f"{image}@{v}", "image": image, "texture": texture, "strength": float(v)}
                row.update({m: float(a[c, v]) for m, a in values.items()})
                row.update((extra or {}).get((c, v), {}))
                rows.append(row)
        self.views[key] = pd.DataFrame(rows)
        self.rows.append({"key": key, "detector": detector, "selector": selector, "descriptor": descriptor,
                          "transform": transform, "status": "ok", "by_reference_count": by_count})
        return key

    def add_by_count(self, detector, descriptor, success_by_count: dict[float, np.ndarray]):
        """A Table 7 cell: per pair (clusters), one row per reference feature count."""
        key = "__".join([detector, "nms", descriptor, "incremental"])
        rows = []
        for count, success in success_by_count.items():
            for c, (texture, image) in enumerate(cluster_ids(len(success), "incremental")):
                rows.append({"view": f"{image}#{count}", "image": image, "texture": texture,
                             "reference_count": float(count), "pose_success": float(success[c])})
        self.views[key] = pd.DataFrame(rows)
        summary = {f"{float(c)}": {"pose_success": float(np.mean(s))} for c, s in success_by_count.items()}
        self.rows.append({"key": key, "detector": detector, "selector": "nms", "descriptor": descriptor,
                          "transform": "incremental", "status": "ok", "by_reference_count": summary})

    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(self.rows)
