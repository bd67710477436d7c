"""Where a finished pair sweep's task seconds went, per pair: detection per detector (both views), description per
descriptor (summed over the detectors it describes), matching and pose (summed over the cells).

    python benchmarks/sweep_breakdown.py multirun/<date>/<time>/0

Reads the job's per-pair rows as the reproduction's cost accounting does (``gtsweep.reproduction.task_costs``:
one detection per (detector, view), reused by every cell of that detector through the keypoint cache; ``t_detect``
is the test view's, and the reference view's detection, not timed apart, is counted at the same cost). Each cell
describes (both views), matches and estimates the pose for itself, so those count per cell. Prints figures; no
pass/fail.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy, as every benchmark
import argparse
from pathlib import Path

import pandas as pd

from gtsweep.reproduction.task_costs import detections, view_rows


def breakdown(rows: pd.DataFrame) -> dict:
    """Seconds per pair of the sweep whose rows (:func:`view_rows`) are ``rows``."""
    pairs = rows["view"].nunique()
    detection = 2 * detections(rows).groupby("detector")["t_detect"].mean().sort_values(ascending=False)
    description = (rows.groupby("descriptor")["t_describe"].sum() / pairs).sort_values(ascending=False)
    return {"pairs": pairs, "detection": detection, "description": description,
            "matching": rows["t_match"].sum() / pairs, "pose": rows["t_pose"].sum() / pairs}


def _listing(series: pd.Series) -> str:
    return ", ".join(f"{name} {seconds:.2f}" for name, seconds in series.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("job", type=Path, help="a finished sweep's job directory (the one holding cells/)")
    job = parser.parse_args().job
    rows = view_rows(job)
    if not len(rows):
        raise SystemExit(f"no evaluated cell with per-pair rows under {job / 'cells'}")
    parts = breakdown(rows)
    total = parts["detection"].sum() + parts["description"].sum() + parts["matching"] + parts["pose"]
    cells = rows.groupby(["detector", "descriptor", "transform"]).ngroups
    print(f"{cells} evaluated cells, {parts['pairs']} pairs")
    print(f"per pair {total:.1f} CPU-s; over the sweep {total * parts['pairs'] / 3600:.2f} CPU-hours")
    print(f"  detection {parts['detection'].sum():.2f} s (both views): {_listing(parts['detection'])}")
    print(f"  description {parts['description'].sum():.2f} s: {_listing(parts['description'])}")
    print(f"  matching {parts['matching']:.2f} s, pose {parts['pose']:.2f} s")


if __name__ == "__main__":
    main()
