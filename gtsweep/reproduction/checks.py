"""Checks before trusting committed rows on this machine: the renderer gives the same bytes for a sample of the
recorded images and pairs (their fingerprints hold the bytes' digest), else one line says so; or, for every
recorded item, the audit."""
from __future__ import annotations

import yaml

from gtsweep.core.errors import BadInput
from gtsweep.core.numeric_backends import numpy_dispatch_pinned
from gtsweep.core.paths import CONF_DIR
from gtsweep.datasets import load_dataset
from gtsweep.orchestration.view_reuse import item_fingerprints
from gtsweep.reproduction.state import State, item_number


def sample_items(state: State, per_split: int = 1) -> list[tuple[str, str, str]]:
    """(split, item, recorded fingerprint) of the first recorded items of each split."""
    found, seen = [], {}
    for chunk in state.chunks:
        split = chunk["split"]
        for item, fingerprint in sorted(chunk.get("items", {}).items()):
            if fingerprint and seen.get(split, 0) < per_split:
                found.append((split, item, fingerprint))
                seen[split] = seen.get(split, 0) + 1
    return found


def recorded_items(state: State) -> dict[str, dict[str, str]]:
    """Every recorded item's fingerprint, per split."""
    found: dict[str, dict[str, str]] = {}
    for chunk in state.chunks:
        found.setdefault(chunk["split"], {}).update({k: v for k, v in chunk.get("items", {}).items() if v})
    return found


def audit(state: State, cache_dir: str, textures: list[str] | None = None) -> tuple[int, list[str]]:
    """Render every recorded item anew (each split of each texture at its largest recorded count) and compare its
    fingerprint with the record: ``(items compared, the items that differ)``. Minutes, where :func:`rerender`
    takes seconds: a machine's full answer to "does it render the state's bytes"."""
    unknown = sorted(set(textures or []) - set(state.textures()))
    if unknown:
        raise BadInput(f"no recorded texture {', '.join(unknown)} (the state's: {', '.join(state.textures())})")
    options = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())
    compared, differ = 0, []
    for split, items in recorded_items(state).items():
        items = {k: v for k, v in items.items() if textures is None or k.split("/")[0] in textures}
        if not items:
            continue
        counts = {"n_synthetic": 0, "n_incremental": 0, "n_absolute": 0,
                  f"n_{split}": max(item_number(item) for item in items) + 1}
        here = item_fingerprints(load_dataset({**options, **counts, "cache_dir": cache_dir,
                                               **({"textures": textures} if textures else {})}), split)
        compared += len(items)
        differ += sorted(item for item, recorded in items.items() if here.get(item) != recorded)
    return compared, differ


def rerender(state: State, cache_dir: str, per_split: int = 1) -> int:
    """Render each sampled item alone (its texture, its window) and compare its fingerprint with the record;
    returns how many were checked. A mismatch is one line (:class:`BadInput`)."""
    options = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())
    checked = 0
    for split, item, recorded in sample_items(state, per_split):
        texture, number = item.split("/")[0], item_number(item)
        counts = {"n_synthetic": 0, "n_incremental": 0, "n_absolute": 0, f"n_{split}": number + 1}
        dataset = load_dataset({**options, **counts, "textures": [texture], "cache_dir": cache_dir,
                                "skip_first": {split: number}})
        here = item_fingerprints(dataset, split).get(item)
        if here != recorded:
            raise BadInput(f"the renderer here gives other bytes for {item} than the committed state records "
                           f"(fingerprint {here} vs {recorded}): the rows cannot be trusted on this machine "
                           f"({_platform_hint()})")
        checked += 1
    return checked


def _platform_hint() -> str:
    """Why a view may render to other bytes here (:mod:`gtsweep.core.numeric_backends`)."""
    if not numpy_dispatch_pinned():
        return "NumPy runs its AVX-512 loops in this process: import gtsweep before NumPy"
    return "the state was rendered on Linux x86-64 with glibc; see docs/reproduction_run.md, 'Portability'"
