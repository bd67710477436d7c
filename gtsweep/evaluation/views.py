"""The views a shard of a data set yields under a transform: real pairs as they are, synthetic transforms at each
strength (seeded per image and strength, so every process renders the same view)."""
from __future__ import annotations

import math

import numpy as np

from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation.transforms import ViewPair, synthesize


def make_shard(kind: str, items: list[dict]) -> dict:
    """A shard: ``kind`` "synthetic" (items: id, texture, image) or "pairs" (id, texture, reference, test, H)."""
    return {"kind": kind, "items": items}


def rotation_deg(H: np.ndarray) -> float:
    """The magnitude (0-180 degrees) of the rotation in a pair's ground-truth homography (report/rotation.py)."""
    return abs(math.degrees(math.atan2(H[1, 0] - H[0, 1], H[0, 0] + H[1, 1])))


def views(shard: dict, transform: str, transform_cfg: dict, seed: int):
    """``(meta, ViewPair)`` for every view of a shard under a transform (every strength of a synthetic one)."""
    if transform_cfg["kind"] == "pairs":
        for item in shard["items"]:
            full = np.full(item["reference"].shape, 255, np.uint8)
            view = ViewPair(item["reference"], full, item["test"], np.full(item["test"].shape, 255, np.uint8),
                            np.asarray(item["H"], dtype=np.float64), transform, math.nan)
            yield {"view": item["id"], "image": item["id"], "texture": item["texture"], "strength": math.nan,
                   "rotation": rotation_deg(view.H)}, view
        return
    params = transform_cfg.get("params") or {}
    for item in shard["items"]:
        for strength in transform_cfg["strengths"]:
            view = synthesize(transform, item["image"], float(strength),
                              seed=stable_seed(seed, item["id"], strength), **params)
            meta = {"view": f"{item['id']}@{strength}", "image": item["id"], "texture": item["texture"],
                    "strength": float(strength)}
            yield meta, view
