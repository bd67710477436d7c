"""Where a finished pair sweep's task seconds went, per pair: detection per detector (both views), description per
descriptor (summed over the detectors it describes), matching and pose (summed over the cells).

    python benchmarks/sweep_breakdown.py multirun/<date>/<time>/0

Reads the job's ``cells/*.csv`` (one row per pair, the task timings ``t_detect``, ``t_describe``, ``t_match`` and
``t_pose`` in seconds). A detection is made once per (detector, view) and reused by every cell of that detector,
so its seconds count once per detector: the first evaluated cell's mean. ``t_detect`` is the test view's (survey
Table 3's time); the reference view's detection, not timed apart, is counted at the same cost. Each cell
describes (both views), matches and estimates the pose for itself, so those count per cell. Prints figures; no
pass/fail.
"""
from __future__ import annotations

import gtsweep  # noqa: F401 - first, before NumPy, as every benchmark
import argparse
import json
from pathlib import Path

import pandas as pd

TIMINGS = ["t_detect", "t_describe", "t_match", "t_pose"]


def cell_means(job: Path) -> pd.DataFrame:
    """One row per evaluated cell: its detector, descriptor, pair count and mean task seconds per pair."""
    rows = []
    for summary in sorted((job / "cells").glob("*.json")):
        cell = json.loads(summary.read_text())
        table = summary.with_suffix(".csv")
        if cell.get("status") != "ok" or not table.exists():
            continue
        timings = pd.read_csv(table, usecols=TIMINGS)
        rows.append({"detector": cell["methods"]["detector"], "descriptor": cell["methods"]["descriptor"],
                     "pairs": len(timings), **timings.mean().to_dict()})
    if not rows:
        raise SystemExit(f"no evaluated cell with per-pair rows under {job / 'cells'}")
    return pd.DataFrame(rows)


def breakdown(cells: pd.DataFrame) -> dict:
    detection = 2 * cells.groupby("detector", sort=False)["t_detect"].first().sort_values(ascending=False)
    description = cells.groupby("descriptor")["t_describe"].sum().sort_values(ascending=False)
    return {"detection": detection, "description": description, "matching": cells["t_match"].sum(),
            "pose": cells["t_pose"].sum()}


def _listing(series: pd.Series) -> str:
    return ", ".join(f"{name} {seconds:.2f}" for name, seconds in series.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("job", type=Path, help="a finished sweep's job directory (the one holding cells/)")
    cells = cell_means(parser.parse_args().job)
    parts = breakdown(cells)
    total = parts["detection"].sum() + parts["description"].sum() + parts["matching"] + parts["pose"]
    pairs = int(cells["pairs"].max())
    print(f"{len(cells)} evaluated cells, {pairs} pairs each")
    print(f"per pair {total:.1f} CPU-s; over the sweep {total * pairs / 3600:.2f} CPU-hours")
    print(f"  detection {parts['detection'].sum():.2f} s (both views): {_listing(parts['detection'])}")
    print(f"  description {parts['description'].sum():.2f} s: {_listing(parts['description'])}")
    print(f"  matching {parts['matching']:.2f} s, pose {parts['pose']:.2f} s")


if __name__ == "__main__":
    main()
