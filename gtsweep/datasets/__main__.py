"""``python -m gtsweep.datasets [overrides]``: a data set's pair statistics beside the survey's.
``python -m gtsweep.datasets check [overrides]``: do its poses agree with its images (:mod:`gtsweep.datasets.
posecheck`)? Exit 0 when they do, 1 when they do not (the line says which convention would fit), 2 for bad input.

A Hydra application (``--help``, ``--cfg job``, ``--config-dir`` work): overrides are Hydra's, e.g.
``dataset=microgps dataset.root=/data`` or ``dataset.n_incremental=100``.
"""
from __future__ import annotations

import sys

import numpy as np

from gtsweep.core.errors import GtsweepError
from gtsweep.datasets import layout, load_dataset, overlap, rotation_deg, synthetic

#: Survey section 5.2 (Micro-GPS): overlap mean / min, rotation mean (the share below 15 degrees is not given).
SURVEY = {"incremental": (0.227, 0.017, 3.0), "absolute": (0.437, None, 120.0)}
#: Rotations below this many degrees count as "small" (near the same heading).
SMALL_ROTATION_DEG = 15.0


def _summary(overlaps: np.ndarray, rotations: np.ndarray) -> dict:
    if not len(overlaps):
        return {"pairs": 0}
    return {"pairs": len(overlaps), "overlap_mean": overlaps.mean(), "overlap_min": overlaps.min(),
            "overlap_max": overlaps.max(), "rotation_mean": rotations.mean(), "rotation_max": rotations.max(),
            "small_rotation_share": float(np.mean(rotations < SMALL_ROTATION_DEG))}


def pair_statistics(dataset, per_texture: bool = False) -> dict[str, dict]:
    """Per pair kind (and with ``per_texture``, per ``"kind/texture"`` too): count, overlap mean/min/max, rotation
    mean/max (degrees) and the share of rotations below 15 degrees, from the poses."""
    stats, shapes = {}, {}
    for kind in SURVEY:
        pairs = dataset.pairs(kind)
        for p in pairs:  # one image per texture gives its size
            shapes.setdefault(p.texture, p.reference.load().shape)
        overlaps = np.array([overlap(p.reference.pose, p.test.pose, shapes[p.texture]) for p in pairs])
        rotations = np.array([rotation_deg(p.reference.pose, p.test.pose, shapes[p.texture]) for p in pairs])
        stats[kind] = _summary(overlaps, rotations)
        textures = np.array([p.texture for p in pairs])
        for texture in (dataset.textures if per_texture else ()):
            chosen = textures == texture
            stats[f"{kind}/{texture}"] = _summary(overlaps[chosen], rotations[chosen])
    return stats


def format_statistics(name: str, stats: dict) -> str:
    lines = [f"data set '{name}': pair statistics (survey's Micro-GPS numbers in parentheses)",
             f"{'kind':27s} {'pairs':>5s}  {'overlap mean':>16s}  {'overlap min':>15s}  {'overlap max':>11s}"
             f"  {'rotation mean':>16s}  {'rotation max':>12s}  {'< 15°':>11s}"]
    for key, s in stats.items():
        if s["pairs"] == 0:
            lines.append(f"{key:27s} {0:5d}")
            continue
        o_mean, o_min, r_mean = SURVEY[key.split("/")[0]]
        survey_min = f"({o_min:.3f})" if o_min is not None else "(n/a)"
        lines.append(f"{key:27s} {s['pairs']:5d}  {s['overlap_mean']:7.3f} ({o_mean:.3f})  "
                     f"{s['overlap_min']:7.3f} {survey_min}  {s['overlap_max']:11.3f}  "
                     f"{s['rotation_mean']:6.1f}° ({r_mean:5.1f}°)  {s['rotation_max']:11.1f}°  "
                     f"{s['small_rotation_share']:5.1%} (n/a)")
    return "\n".join(lines)


def revisit_line(law) -> str:
    """The absolute pairs' revisit law (layout.revisit_weights) with its analytic mean and share below 15°."""
    law = {**synthetic.PAIR_LAWS["absolute"], **law}
    same, opposite, crossing = layout.revisit_weights(law)
    return (f"absolute rotation law: revisits, same direction {same:.3f}, opposite {opposite:.3f}, crossing "
            f"{crossing:.3f}, heading noise {float(law['heading_noise_deg']):g}°: mean "
            f"{layout.revisit_mean(law):.1f}° "
            f"(survey 120°), {layout.revisit_share_below(law, SMALL_ROTATION_DEG):.1%} below 15° (analytic)")


def main(argv: list[str] | None = None) -> int:
    """Run the Hydra application on ``argv`` (default: the command line)."""
    import hydra

    from gtsweep.core.searchpath import register_help_resolver

    register_help_resolver()
    codes = []
    args = list(sys.argv[1:] if argv is None else argv)
    task = check if args[:1] == ["check"] else describe

    @hydra.main(config_path="pkg://gtsweep.datasets.primary", config_name="dataset_stats", version_base=None)
    def app(cfg) -> None:
        codes.append(task(cfg))

    saved = sys.argv
    sys.argv = [saved[0], *(args[1:] if task is check else args)]
    try:
        app()
    finally:
        sys.argv = saved
    return codes[0] if codes else 0


def check(cfg) -> int:
    """Print the pose check of ``cfg.dataset`` in one line: 0 when the poses agree with the images, 1 when not, 2
    after a one-line error."""
    from gtsweep.datasets.posecheck import check_poses

    try:
        found = check_poses(load_dataset(cfg.dataset))
    except GtsweepError as error:
        print(f"gtsweep.datasets: error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2
    print(found.line())
    return 0 if found.consistent else 1


def describe(cfg) -> int:
    """Print the statistics of ``cfg.dataset``; 2 after a one-line error."""
    try:
        dataset = load_dataset(cfg.dataset)
        print(format_statistics(dataset.name, pair_statistics(dataset, per_texture=len(dataset.textures) > 1)))
        for kind, why in dataset.empty_kinds.items():
            print(f"no {kind} pairs: {why}")
        law = cfg.dataset.get("absolute") or {}
        if cfg.dataset.get("loader") == "synthetic" and law.get("rotation_law") == "revisit":
            print(revisit_line(law))
        seconds = synthetic.generation_seconds(dataset, cfg.dataset.cache_dir) \
            if cfg.dataset.get("loader") == "synthetic" else None
        if seconds is not None:
            print(f"rendered in {seconds:.1f} s (cached under {cfg.dataset.cache_dir}/datasets/; a cached data set "
                  f"loads without rendering)")
    except GtsweepError as error:
        print(f"gtsweep.datasets: error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2
    if dataset.skipped:
        print(f"skipped {len(dataset.skipped)} bad item(s):", *dataset.skipped, sep="\n  ")
    return 0


if __name__ == "__main__":
    sys.exit(main())
