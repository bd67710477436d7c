"""``python -m gtsweep.datasets [overrides]``: a data set's pair statistics beside the survey's.

A Hydra application (``--help``, ``--cfg job``, ``--config-dir`` work): overrides are Hydra's, e.g.
``dataset=microgps dataset.root=/data`` or ``dataset.n_incremental=100``.
"""
from __future__ import annotations

import sys

import numpy as np

from gtsweep.core.errors import GtsweepError
from gtsweep.datasets import load_dataset, overlap, rotation_deg, synthetic

#: Survey section 5.2 (Micro-GPS): overlap mean / min, rotation mean.
SURVEY = {"incremental": (0.227, 0.017, 3.0), "absolute": (0.437, None, 120.0)}


def pair_statistics(dataset) -> dict[str, dict]:
    """Per pair kind: count, overlap mean/min/max and rotation mean/max (degrees), from the poses."""
    stats, shapes = {}, {}
    for kind in SURVEY:
        pairs = dataset.pairs(kind)
        for p in pairs:  # one image per texture gives its size
            shapes.setdefault(p.texture, p.reference.load().shape)
        overlaps = np.array([overlap(p.reference.pose, p.test.pose, shapes[p.texture]) for p in pairs])
        rotations = np.array([rotation_deg(p.reference.pose, p.test.pose) for p in pairs])
        stats[kind] = {"pairs": len(pairs)} if not len(pairs) else {
            "pairs": len(pairs), "overlap_mean": overlaps.mean(), "overlap_min": overlaps.min(),
            "overlap_max": overlaps.max(), "rotation_mean": rotations.mean(), "rotation_max": rotations.max()}
    return stats


def format_statistics(name: str, stats: dict) -> str:
    lines = [f"data set '{name}': pair statistics (survey's Micro-GPS numbers in parentheses)",
             f"{'kind':12s} {'pairs':>5s}  {'overlap mean':>16s}  {'overlap min':>15s}  {'overlap max':>11s}"
             f"  {'rotation mean':>16s}  {'rotation max':>12s}"]
    for kind, s in stats.items():
        if s["pairs"] == 0:
            lines.append(f"{kind:12s} {0:5d}")
            continue
        o_mean, o_min, r_mean = SURVEY[kind]
        survey_min = f"({o_min:.3f})" if o_min is not None else "(n/a)"
        lines.append(f"{kind:12s} {s['pairs']:5d}  {s['overlap_mean']:7.3f} ({o_mean:.3f})  "
                     f"{s['overlap_min']:7.3f} {survey_min}  {s['overlap_max']:11.3f}  "
                     f"{s['rotation_mean']:6.1f}° ({r_mean:5.1f}°)  {s['rotation_max']:11.1f}°")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the Hydra application on ``argv`` (default: the command line)."""
    import hydra

    from gtsweep.core.configs import register_help_resolver

    register_help_resolver()
    codes = []

    @hydra.main(config_path="pkg://gtsweep.datasets.primary", config_name="dataset_stats", version_base=None)
    def app(cfg) -> None:
        codes.append(describe(cfg))

    saved = sys.argv
    sys.argv = [saved[0], *(saved[1:] if argv is None else argv)]
    try:
        app()
    finally:
        sys.argv = saved
    return codes[0] if codes else 0


def describe(cfg) -> int:
    """Print the statistics of ``cfg.dataset``; 2 after a one-line error."""
    try:
        dataset = load_dataset(cfg.dataset)
        print(format_statistics(dataset.name, pair_statistics(dataset)))
        seconds = synthetic.generation_seconds(dataset, cfg.dataset.cache_dir) if dataset.name == "synthetic" \
            else None
        if seconds is not None:
            print(f"rendered in {seconds:.1f} s (cached under {cfg.dataset.cache_dir}/datasets/)")
    except GtsweepError as error:
        print(f"gtsweep.datasets: error: {str(error).splitlines()[0]}", file=sys.stderr)
        return 2
    if dataset.skipped:
        print(f"skipped {len(dataset.skipped)} bad item(s):", *dataset.skipped, sep="\n  ")
    return 0


if __name__ == "__main__":
    sys.exit(main())
