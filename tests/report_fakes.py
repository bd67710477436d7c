"""Result files of a sweep written by hand (no detector runs): per-view rows and summaries of chosen outcomes."""
from __future__ import annotations

import math

import pandas as pd

from gtsweep.orchestration.results import ResultStore, summarize


def fake_cell(directory, detector, descriptor, transform, outcomes, selector="nms", strengths=(None,),
              textures=("gravel",), extra=None, variant=None):
    """Write one cell's per-view rows and summary: ``outcomes`` per pair (or image x strength) 0/1 success;
    ``variant``: e.g. ``{"matcher": "flann", "estimator": "magsac"}`` (in the methods and the key)."""
    rows = []
    per_texture = len(outcomes) // len(textures)
    for i, outcome in enumerate(outcomes):
        texture = textures[i // per_texture]
        image, strength = i // len(strengths), strengths[i % len(strengths)]
        view = f"{texture}/{image:03d}" + ("" if strength is None else f"@{strength}")
        rows.append({"view": view, "image": f"{texture}/{image:03d}", "texture": texture,
                     "strength": math.nan if strength is None else float(strength),
                     **({"pose_success": float(outcome)} if descriptor else {}),
                     **(extra(i) if extra else {})})
    rows = pd.DataFrame(rows)
    variant = variant or {}
    key = "__".join([detector, selector, descriptor or "none", transform, *variant.values()])
    experiment = "pose" if descriptor else "detection"
    summary = {"key": key, "methods": {"detector": detector, "selector": selector, "descriptor": descriptor,
                                       "transform": transform, **variant}, "status": "ok", "experiment": experiment,
               **summarize(rows, experiment)}
    ResultStore(directory).write_cell(key, summary, rows)
    return key
