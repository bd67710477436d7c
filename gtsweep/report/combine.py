"""One table and one report across the jobs of a multirun (``python -m gtsweep -m dataset.seed=0,1 ...``).

Jobs that differ only in ``seed`` or ``dataset.seed`` are repeats of one setting. ``dataset.seed`` draws the images
and pairs (another sample of the data); ``seed`` only the evaluation's random draws (RANSAC, the synthetic transforms'
noise) on the same images, so its spread is RANSAC's alone: the summary's header says which one varied. Each cell gets
the mean of its metrics over the repeats (:func:`~gtsweep.report.breakdown.mean_summary`), their spread (sample standard
deviation) and the number of repeats. Jobs that differ in anything else are separate settings (named by the overrides
that differ, e.g.
``selector.nms.params.n=500``), side by side.
Written into ``<sweep dir>/combined/``::

    all_results.csv  every cell of every job: setting, seed, job, methods, status, metrics (not results.csv:
                     a glob of the jobs' */results.csv must not find it)
    summary.csv      per setting and cell: <metric>_mean, <metric>_std, n (repeats that evaluated it)
    summary.md       the headline metric per setting and cell as mean ± std (n)
    settings.md/.csv several settings: pose success per cell and setting with intervals, paired tests against
                     the first setting, the survey's value (gtsweep.report.settings)
    report/          the survey's tables and plots of the means (report/<setting>/ when there are several)
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable

import pandas as pd

from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.errors import GtsweepError
from gtsweep.core.rundirs import COMBINED, REPORT
from gtsweep.evaluation import schema
from gtsweep.orchestration.results import VARIANT_COLUMNS, summary_table
from gtsweep.report.breakdown import mean_summary
from gtsweep.report.samples import load_views
from gtsweep.report.scale import Scale, load_scale
from gtsweep.report.settings import write_settings
from gtsweep.report.tables import ALPHA, load_summaries

SEED = re.compile(r"^\+*(?P<key>(?:dataset\.)?seed)=(?P<value>.*)$")
#: What each seed varies, for the summary's header.
VARIES = {"dataset.seed": "dataset.seed: the images and pairs are drawn anew for each repeat",
          "seed": "seed: RANSAC's and the synthetic transforms' draws only, on the same images and pairs (fixed by "
                  "dataset.seed; -m dataset.seed=0,1 varies them)"}


def jobs_of(sweep_dir: Path) -> list[dict]:
    """The jobs of a multirun that wrote results: directory, seed and setting (the overrides other than the seed
    that differ between the jobs; "all" when only the seed does)."""
    jobs = []
    for record in sorted(Path(sweep_dir).glob("*/sweep.json"), key=lambda p: _job_order(p.parent.name)):
        overrides = json.loads(record.read_text()).get("overrides") or []
        if list(record.parent.glob("cells/*.json")):
            jobs.append({"dir": record.parent, "job": record.parent.name, "overrides": overrides})
    shared = set.intersection(*(set(job["overrides"]) for job in jobs)) if jobs else set()
    for job in jobs:
        seeds = {m["key"]: m["value"] for m in map(SEED.match, job["overrides"]) if m}
        job["seeds"] = seeds
        job["seed"] = ("/".join(seeds[k] for k in sorted(seeds)) if len(seeds) > 1
                       else int(next(iter(seeds.values()), 0)))
        job["setting"] = " ".join(o for o in job["overrides"] if o not in shared and not SEED.match(o)) or "all"
    return jobs


def _job_order(name: str):
    return (0, int(name)) if name.isdigit() else (1, name)


#: ``write(summaries, out_dir, views, scale) -> files``: a kind's report of the repeats' mean summaries, with every
#: repeat's per-view rows (``{key: rows}``, a ``repeat`` column telling them apart) and the data set's scale.
ReportWriter = Callable[[list[dict], Path, dict, Scale], list[Path]]


def combine(sweep_dir: str | Path, write: ReportWriter, alpha: float = ALPHA) -> list[Path]:
    """Write ``<sweep dir>/combined/`` from the jobs' result files; returns the files written. ``write``: the
    report of the jobs' experiment kind (its entry's). The report's intervals come from every repeat's per-view
    rows (each repeat a stratum of its own, images matched across)."""
    sweep_dir = Path(sweep_dir)
    jobs = jobs_of(sweep_dir)
    if not jobs:
        raise GtsweepError(f"no job of the multirun in '{sweep_dir}' wrote results")
    out = sweep_dir / COMBINED
    out.mkdir(parents=True, exist_ok=True)
    by_job = {job["job"]: load_summaries(job["dir"]) for job in jobs}
    rows = pd.concat([summary_table(by_job[job["job"]]).assign(setting=job["setting"], seed=job["seed"],
                                                                job=job["job"]) for job in jobs], ignore_index=True)
    rows = rows[["setting", "seed", "job", *[c for c in rows.columns if c not in ("setting", "seed", "job")]]]
    files = [_write(out / "all_results.csv", rows.to_csv(index=False))]
    summary = repeat_table(rows)
    files.append(_write(out / "summary.csv", summary.to_csv(index=False)))
    headlines = {schema.headline(schema.experiment_of(s)) for summaries in by_job.values() for s in summaries}
    files.append(_write(out / "summary.md", headline_markdown(summary, jobs, headlines)))
    settings = sorted({job["setting"] for job in jobs})
    for setting in settings:
        cells, views = _repeats(jobs, by_job, setting)
        target = out / REPORT / (_slug(setting) if len(settings) > 1 else "")
        files += write([mean_summary(v) for v in cells.values()], target,
                       {k: pd.concat(v, ignore_index=True) for k, v in views.items()}, load_scale(jobs[0]["dir"]))
    files += write_settings(out, jobs, by_job, {job["job"]: load_views(job["dir"]) for job in jobs}, alpha)
    return files


def _repeats(jobs: list[dict], by_job: dict[str, list[dict]], setting: str) -> tuple[dict, dict]:
    """The summaries (``{key: [one per repeat]}``) and per-view rows (``{key: [frames]}``) of one setting."""
    cells: dict[str, list[dict]] = {}
    views: dict[str, list[pd.DataFrame]] = {}
    for job in (j for j in jobs if j["setting"] == setting):
        for s in by_job[job["job"]]:
            cells.setdefault(s["key"], []).append(s)
        for key, rows in load_views(job["dir"]).items():
            views.setdefault(key, []).append(rows.assign(repeat=job["job"]))
    return cells, views


def repeat_table(rows: pd.DataFrame) -> pd.DataFrame:
    """Per setting and cell: mean and sample standard deviation of every metric over the repeats, and n."""
    metrics = schema.ordered(c for c in rows.columns if c in schema.METRICS)
    keys = ["setting", *[c for c in METHOD_GROUPS if c in rows]]
    ok = rows[rows["status"] == "ok"].copy()
    for metric in metrics:
        ok[metric] = pd.to_numeric(ok[metric], errors="coerce")
    grouped = ok.groupby(keys, dropna=False, sort=False)
    table = grouped[metrics].agg(["mean", "std"])
    table.columns = [f"{metric}_{stat}" for metric, stat in table.columns]
    table.insert(0, "n", grouped.size())
    table.insert(1, "seeds", grouped["seed"].agg(lambda s: " ".join(str(v) for v in sorted(s))))
    return table.reset_index()


def headline_markdown(summary: pd.DataFrame, jobs: list[dict], headlines) -> str:
    """The headline metric of each cell as ``mean ± std (n)``, per setting."""
    seeds = sorted({job["seed"] for job in jobs})
    varied = [VARIES[key] for key in sorted(VARIES) if len({job["seeds"].get(key) for job in jobs}) > 1]
    lines = [f"**Multirun: {len(jobs)} jobs, seeds {', '.join(map(str, seeds))}; mean ± std over the seeds "
             f"(n = repeats that evaluated the cell)**", "", *(f"Varied: {v}." for v in varied), ""]
    for metric in [m for m in schema.ordered(headlines) if f"{m}_mean" in summary]:
        part = summary[summary[f"{metric}_mean"].notna()]
        if part.empty:
            continue
        columns = [c for c in ["setting", *METHOD_GROUPS]
                   if c in part and (c not in VARIANT_COLUMNS or part[c].nunique() > 1)]
        header = f"{metric} ({schema.METRICS[metric].unit}): mean ± std (n)"
        lines += [f"{metric}:", "", "| " + " | ".join([*columns, header]) + " |", "|" + "---|" * (len(columns) + 1)]
        for row in part.itertuples(index=False):
            values = [str(getattr(row, c)) if pd.notna(getattr(row, c)) else "" for c in columns]
            std = getattr(row, f"{metric}_std")
            spread = f" ± {std:.3f}" if pd.notna(std) else ""
            lines.append("| " + " | ".join([*values, f"{getattr(row, f'{metric}_mean'):.3f}{spread} ({row.n})"])
                         + " |")
        lines.append("")
    return "\n".join(lines)


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=,-]+", "_", text.replace("[", "").replace("]", "")).strip("_")[:80] or "all"


def _write(path: Path, text: str) -> Path:
    path.write_text(text if text.endswith("\n") else text + "\n")
    return path
