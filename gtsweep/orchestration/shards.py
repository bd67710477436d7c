"""The images a run evaluates, loaded once and cut into shards (the unit of work of a task).

Both drivers use :func:`load_shards`: the sweep on the synthetic split in shards of ``runner.shard_size``, the
optimiser on the optimisation split in one shard (a trial is one task).
"""
from __future__ import annotations

from typing import Mapping

from gtsweep.core.errors import BadInput
from gtsweep.evaluation.views import make_shard


def shard_kind(transform: str, transform_cfg: Mapping) -> str:
    """Which shards a transform reads: ``"synthetic"`` for a synthetic transform, else its pair split's name."""
    return "synthetic" if transform_cfg["kind"] == "synthetic" else transform


def load_shards(dataset, transforms: Mapping[str, Mapping], shard_size: int | None = None,
                images: str = "synthetic") -> dict[str, list[dict]]:
    """Shards per :func:`shard_kind` of ``transforms``: the ``images`` split for the synthetic transforms, the
    pairs of each pair split; ``shard_size`` images or pairs each (None: all in one shard). Every image is read
    here, so bad data stops the run before any work."""
    shards = {}
    for kind in sorted({shard_kind(name, cfg) for name, cfg in transforms.items()}):
        if kind == "synthetic":
            split = images
            items = [{"id": s.id, "texture": s.texture, "image": s.load()} for s in dataset.images(images)]
        else:
            split = kind
            items = [{"id": p.id, "texture": p.texture, "reference": p.reference.load(), "test": p.test.load(),
                      "H": p.H} for p in dataset.pairs(kind)]
        if not items:
            raise BadInput(f"data set '{dataset.name}' has no {split} images: nothing to evaluate "
                           f"(dataset.n_{split}?)")
        size = shard_size or len(items)
        shards[kind] = [make_shard("synthetic" if kind == "synthetic" else "pairs", items[i:i + size])
                        for i in range(0, len(items), size)]
    return shards
