"""Resume on a grown data set: a cell keeps the per-view rows of the images or pairs it already evaluated and
evaluates only the new ones.

A data set's first n images or pairs per texture are the same for any larger count (the embedded data sets
render them from one generator per split and pair; ``tests/test_survey.py``), so a cell evaluated at n and asked
again at 2n computes rows for the first n that are identical to those it holds: every per-view number is seeded
by the view's own id (:mod:`gtsweep.evaluation.views`, :func:`~gtsweep.core.seeds.stable_seed`), never by its shard
or its neighbours. A cell's rows are reused under its *reuse key*, the hash of everything that determines its
numbers except the data set's fingerprint (its methods and their full configuration, the experiment, the seed,
the versions of the libraries that detect), and per image or pair under that item's own fingerprint (its id,
texture, the bytes of its image files and its pose or homography): anything that changes the numbers changes one
of them and the rows are computed again. What a cell's rows cover is written beside them
(:meth:`~gtsweep.orchestration.results.ResultStore.write_cell`, ``reuse/<cell>.json``).

The merged rows are in the order a run from scratch writes them (the data set's order of images or pairs), so a
cell grown from n to 2n equals a cell evaluated at 2n at once, bit for bit (timings aside: the reused rows keep the
times measured when they were computed).
"""
from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.core.config import config_hash
from gtsweep.datasets.core import fingerprint_of
from gtsweep.orchestration.cache import library_versions
from gtsweep.orchestration.grid import MethodCell, MethodGrid
from gtsweep.orchestration.results import ResultStore, stored_rows
from gtsweep.orchestration.shards import shard_kind

#: What stands for the data set fingerprint in a reuse key: the items carry their own fingerprints.
PER_ITEM = "per image or pair (see the coverage's items)"


def _file_digest(sample) -> str | None:
    if sample.path is None or not Path(sample.path).is_file():
        return None
    return hashlib.blake2b(Path(sample.path).read_bytes(), digest_size=16).hexdigest()


def item_fingerprints(dataset, kind: str) -> dict[str, str | None]:
    """``{id: fingerprint}`` of the images (``kind`` "synthetic": the synthetic split) or pairs of ``kind``, in the
    data set's order; None for an item without an image file (never reused)."""
    if kind == "synthetic":
        found = {}
        for s in dataset.images("synthetic"):
            digest = _file_digest(s)
            found[s.id] = fingerprint_of(s.id, s.texture, digest, s.pose) if digest else None
        return found
    found = {}
    for p in dataset.pairs(kind):
        digests = (_file_digest(p.reference), _file_digest(p.test))
        found[p.id] = fingerprint_of(p.id, p.texture, *digests, p.H) if all(digests) else None
    return found


def reuse_key(grid, cell, seed: int, versions: dict) -> str:
    """The key a cell's rows are reused under: its configuration without the data set's fingerprint, and the
    versions of the libraries that compute it."""
    return config_hash({"cell": grid.cell_config(cell, PER_ITEM, seed), "versions": versions})


def subset(dataset, ids: set[str]):
    """``dataset`` with only the images and pairs whose ids are in ``ids`` (in their order)."""
    pairs = None if dataset.kind_pairs is None else \
        {kind: [p for p in items if p.id in ids] for kind, items in dataset.kind_pairs.items()}
    return dataclasses.replace(dataset, split_images={split: [s for s in items if s.id in ids]
                                                      for split, items in dataset.split_images.items()},
                               kind_pairs=pairs)


class ViewReuse:
    """Which images or pairs each pending cell of a sweep still needs, and its rows once evaluated.

    ``reused`` and ``evaluated`` count (cell, image or pair) combinations taken from the stored rows and sent to
    evaluation."""

    def __init__(self, store: ResultStore, grid: MethodGrid, dataset, seed: int, wrap=lambda dataset: dataset):
        self.store, self.grid, self.seed, self.wrap = store, grid, seed, wrap  # wrap: a cut data set as the sweep's
        kinds = {shard_kind(name, cfg) for name, cfg in grid.transforms.items()}
        self.items = {kind: item_fingerprints(dataset, kind) for kind in sorted(kinds)}
        self.dataset = dataset
        self.kept: dict[str, pd.DataFrame] = {}
        self.reused = self.evaluated = 0

    def _kind(self, cell: MethodCell) -> str:
        return shard_kind(cell.transform, self.grid.transforms[cell.transform])

    def reuse_key(self, cell: MethodCell) -> str:
        return reuse_key(self.grid, cell, self.seed, library_versions())

    def coverage(self, cell: MethodCell) -> dict:
        """What a cell evaluated on this data set covers: its reuse key and its items' fingerprints."""
        return {"reuse_key": self.reuse_key(cell), "items": self.items[self._kind(cell)]}

    def plan(self, cells: list[MethodCell]) -> tuple[list[MethodCell], list[tuple[object, list[MethodCell]]]]:
        """``(ready, groups)``: the cells whose stored rows cover every item already, and the others grouped by
        the items they still need, each group with the data set cut to those items."""
        ready, groups = [], {}
        for cell in cells:
            items = self.items[self._kind(cell)]
            stored = self.store.coverage(cell.key)
            same = set()
            if stored is not None and stored.get("reuse_key") == self.reuse_key(cell):
                held = stored.get("items") or {}
                same = {i for i, fp in items.items() if fp is not None and held.get(i) == fp}
            rows = self.store.rows(cell.key) if same else pd.DataFrame()
            if "image" not in rows:  # rows without their images named cannot be split: all evaluated again
                same = set()
            else:
                self.kept[cell.key] = rows[rows["image"].astype(str).isin(same)]
            missing = tuple(i for i in items if i not in same)
            self.reused, self.evaluated = self.reused + len(same), self.evaluated + len(missing)
            if missing:
                groups.setdefault(missing, []).append(cell)
            else:
                ready.append(cell)
        return ready, [(self.wrap(subset(self.dataset, set(missing))), group) for missing, group in groups.items()]

    def complete(self, cell: MethodCell, outcome: dict) -> dict:
        """``outcome`` of a cell's new items, with the rows it kept merged in, in the data set's order."""
        kept = self.kept.pop(cell.key, None)
        if kept is None or "rows" not in outcome:
            return outcome
        new = outcome["rows"]
        if len(new):
            new = stored_rows(new, {"experiment": self.grid.experiment["name"], "methods": cell.methods})
            merged = pd.concat([kept, new], ignore_index=True)
        else:
            merged = kept.reset_index(drop=True)
        position = {item: k for k, item in enumerate(self.items[self._kind(cell)])}
        order = np.argsort(merged["image"].astype(str).map(position).to_numpy(), kind="stable")
        return {**outcome, "rows": merged.iloc[order].reset_index(drop=True)}
