"""The detector parameters a reproduction used, read from the headers of the tuned files (``conf/detector/tuned``):
per detector the study's trials and why it stopped, the defaults' and the tuned parameters' views below N keypoints
and repeatability, the selector, and the tuned values (survey section 5: "parameter optimization" on 3 images
per texture kept apart from the test images). The headers are written by
:mod:`gtsweep.experiments.optimize.tuned_files`, so
the table needs no study database: a fresh clone has none.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

_TRIALS = re.compile(r"best of (\d+) complete trials: trial (\d+)")
_SCORE = r"score (-?[\d.]+) = repeatability ([\d.nan]+) - (\d+) of (\d+) views with < (\d+) keypoints"
_BEST = re.compile(r"objective repeatability: " + _SCORE)
_DEFAULTS = re.compile(r"Defaults \(trial \d+\): " + _SCORE)
_STOP = re.compile(r"stopped: ([^.;]+(?:\.\d+[^.;]*)?)\.")
_SELECTOR = re.compile(r"Selector: (\w+)")
_FINGERPRINT = re.compile(r"Data set fingerprint ([0-9a-f]+)")


def read_header(path: Path) -> dict:
    """What one tuned file's header states (keys missing when the header predates them) and its tuned values."""
    import yaml

    text = Path(path).read_text()
    header = " ".join(line[1:].strip() for line in text.splitlines() if line.startswith("#"))
    row: dict = {"detector": Path(path).stem}
    if m := _TRIALS.search(header):
        row.update(trials=int(m.group(1)), best_trial=int(m.group(2)))
    for key, pattern in (("tuned", _BEST), ("defaults", _DEFAULTS)):
        if m := pattern.search(header):
            row[f"{key}_repeatability"] = float(m.group(2))
            row[f"{key}_few"], row["views"], row["min_keypoints"] = int(m.group(3)), int(m.group(4)), int(m.group(5))
    for key, pattern in (("stop", _STOP), ("selector", _SELECTOR), ("fingerprint", _FINGERPRINT)):
        if m := pattern.search(header):
            row[key] = m.group(1)
    node = (yaml.safe_load(text) or {}).get(row["detector"]) or {}  # beside it: the defaults list (its schema)
    space, params = node.get("search_space") or {}, node.get("params") or {}
    row["values"] = {k: params[k] for k in space if k in params}
    return row


def tuned_rows(directory: Path) -> list[dict]:
    """:func:`read_header` of every tuned file in ``directory``, by detector name."""
    return [read_header(p) for p in sorted(Path(directory).glob("*.yaml"))]


def _value(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def _change(row: dict, key: str, fmt) -> str:
    before, after = row.get(f"defaults_{key}"), row.get(f"tuned_{key}")
    if after is None:
        return "?"
    if before is None or isinstance(before, float) and math.isnan(before):
        return fmt(after)
    return f"{fmt(before)} → {fmt(after)}"


def tuning_table(directory: Path) -> str:
    """A Markdown table of :func:`tuned_rows`: one line per tuned detector."""
    rows = tuned_rows(directory)
    if not rows:
        return ""
    n = next((r["min_keypoints"] for r in rows if "min_keypoints" in r), 100)
    lines = [f"| detector | trials | stopped | selector | views < {n} KPs (defaults → tuned) of views | "
             "repeatability (defaults → tuned) | tuned parameters |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        values = ", ".join(f"{k}={_value(v)}" for k, v in r["values"].items())
        lines.append(f"| {r['detector']} | {r.get('trials', '?')} | {r.get('stop', '?')} | {r.get('selector', '?')} "
                     f"| {_change(r, 'few', str)} of {r.get('views', '?')} "
                     f"| {_change(r, 'repeatability', lambda x: f'{x:.2f}')} | {values} |")
    return "\n".join(lines)
