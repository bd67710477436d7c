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


def recorded_items(state: State) -> dict[str, dict[str, str]]:
    """Every recorded item's fingerprint, per split, in the order the chunks first record them (a chunk's items
    sorted)."""
    found: dict[str, dict[str, str]] = {}
    for chunk in state.chunks:
        items = found.setdefault(chunk["split"], {})
        for item, fingerprint in sorted(chunk.get("items", {}).items()):
            if fingerprint:
                items.setdefault(item, fingerprint)
    return found


def sample_items(state: State, per_split: int = 1) -> list[tuple[str, str, str]]:
    """(split, item, recorded fingerprint) of the first recorded items of each split."""
    return [(split, item, fingerprint) for split, items in recorded_items(state).items()
            for item, fingerprint in list(items.items())[:per_split]]


def fingerprints_here(split: str, count: int, cache_dir: str, textures: list[str] | None = None,
                      skip: int = 0) -> dict[str, str]:
    """The fingerprints of the survey data set's ``split`` items ``skip`` to ``count`` - 1 (of ``textures``, else
    all), rendered on this machine."""
    options = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())
    counts = {"n_synthetic": 0, "n_incremental": 0, "n_absolute": 0, f"n_{split}": count}
    dataset = load_dataset({**options, **counts, "cache_dir": cache_dir, "skip_first": {split: skip},
                            **({"textures": textures} if textures else {})})
    return item_fingerprints(dataset, split)


def audit(state: State, cache_dir: str, textures: list[str] | None = None) -> tuple[int, list[str]]:
    """Render every recorded item anew (each split of each texture at its largest recorded count) and compare its
    fingerprint with the record: ``(items compared, the items that differ)``. Minutes, where :func:`rerender`
    takes seconds: a machine's full answer to "does it render the state's bytes"."""
    unknown = sorted(set(textures or []) - set(state.textures()))
    if unknown:
        raise BadInput(f"no recorded texture {', '.join(unknown)} (the state's: {', '.join(state.textures())})")
    compared, differ = 0, []
    for split, items in recorded_items(state).items():
        items = {k: v for k, v in items.items() if textures is None or k.split("/")[0] in textures}
        if not items:
            continue
        here = fingerprints_here(split, max(item_number(item) for item in items) + 1, cache_dir, textures)
        compared += len(items)
        differ += sorted(item for item, recorded in items.items() if here.get(item) != recorded)
    return compared, differ


def rerender(state: State, cache_dir: str, per_split: int = 1) -> int:
    """Render each sampled item alone (its texture, its window) and compare its fingerprint with the record;
    returns how many were checked. A mismatch is one line (:class:`BadInput`)."""
    checked = 0
    for split, item, recorded in sample_items(state, per_split):
        number = item_number(item)
        here = fingerprints_here(split, number + 1, cache_dir, [item.split("/")[0]], skip=number).get(item)
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
