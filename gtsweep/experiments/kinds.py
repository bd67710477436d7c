"""The experiment registry: each kind declares its cells (a :class:`~gtsweep.orchestration.skeleton.CellWork` on
the one sweep skeleton) or a job of its own, its metrics (from :mod:`gtsweep.evaluation.schema`), its terminal
summary and how its report is written.

A new kind is one :class:`Experiment` entry (``EXPERIMENTS.register(...)``, e.g. from a plug-in module) and one
``conf/experiment/<name>.yaml`` with ``name: <name>``; its metrics are declared with
:func:`gtsweep.evaluation.schema.add_experiment`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

from gtsweep.core.registry import Registry
from gtsweep.evaluation import schema
from gtsweep.experiments.localization.cells import LOCALIZATION
from gtsweep.experiments.localization.report import format_localization, write_localization_report
from gtsweep.experiments.pairs.cells import PAIRS
from gtsweep.experiments.pairs.summary import format_outcome
from gtsweep.orchestration.skeleton import CellWork, SweepOutcome
from gtsweep.orchestration.skeleton import run_sweep as run_cells
from gtsweep.report.combine import combine
from gtsweep.report.output import write_report
from gtsweep.report.samples import Views
from gtsweep.report.scale import Scale
from gtsweep.report.tables import ALPHA, Table


@dataclass(frozen=True)
class ReportOptions:
    """What a report may use besides the cells' summaries: plots or not, the per-view rows (loaded on demand),
    per-texture breakdowns, the paired tests' significance level, the data set's scale."""

    plots: bool = True
    views: Callable[[], Views | None] = lambda: None
    by: str | None = None
    alpha: float = 0.05
    scale: Scale | None = None


#: ``report(summaries, out_dir, options) -> (tables, files)``.
Report = Callable[[list[dict], Path, ReportOptions], "tuple[list[Table], list[Path]]"]
#: ``summary(outcome, tables) -> str``: what the terminal shows at the end of a sweep.
Summary = Callable[[SweepOutcome, list[Table]], str]


@dataclass(frozen=True)
class Experiment:
    """One experiment kind. ``cells``: its grid and evaluation on the sweep skeleton; or ``job``: a job of its own
    (``job(cfg, output_dir)``, e.g. parameter optimisation). ``report`` and ``summary`` for a sweep's kind;
    ``budget_scale``: its report states the keypoint budget's scale (not only the success radius)."""

    name: str
    label: str
    cells: CellWork | None = None
    report: Report | None = None
    summary: Summary | None = None
    job: Callable[[Mapping, Path], None] | None = None
    budget_scale: bool = True

    @property
    def metrics(self) -> list[schema.Metric]:
        """The per-view columns of its rows and how a cell aggregates them, from the schema."""
        return schema.metrics_of(self.name)


def pair_report(summaries: list[dict], out_dir: Path, options: ReportOptions):
    """The survey's tables with intervals and ties, the per-cell and per-strength tables and the plots."""
    return write_report(summaries, out_dir, plots=options.plots, views=options.views(), by=options.by,
                        alpha=options.alpha, scale=options.scale)


def localization_report(summaries: list[dict], out_dir: Path, options: ReportOptions):
    """The localization tables and the map-size plot."""
    return write_localization_report(summaries, out_dir, options.plots)


def optimize_job(cfg: Mapping, output_dir: Path) -> None:
    from gtsweep.experiments.optimize.driver import main

    main(cfg, output_dir)


EXPERIMENTS: Registry[Experiment] = Registry("experiment", [
    Experiment("detection", "keypoint detection (survey Tables 2, 3)", PAIRS, pair_report, format_outcome),
    Experiment("matching", "detection and matching", PAIRS, pair_report, format_outcome),
    Experiment("pose", "detection, matching and pose (survey Tables 4-7)", PAIRS, pair_report, format_outcome),
    Experiment("localization", "localization against a map per floor", LOCALIZATION, localization_report,
               format_localization, budget_scale=False),
    Experiment("optimize", "parameter optimisation with Optuna", job=optimize_job),
], spec=Experiment)


def recorded_kind(summaries: list[dict]) -> Experiment:
    """The experiment kind the cells of a run recorded (a run has one kind)."""
    kinds = {schema.experiment_of(s) for s in summaries}
    reports = {EXPERIMENTS.get(kind).report for kind in kinds}
    if len(reports) > 1:
        from gtsweep.core.errors import BadInput

        raise BadInput(f"the cells are of experiments with different reports: {', '.join(sorted(kinds))}")
    return EXPERIMENTS.get(min(kinds) if kinds else "pose")


def run_sweep(cfg: Mapping, output_dir: str | Path, **options) -> SweepOutcome:
    """The sweep of ``cfg`` on the sweep skeleton, with the cells of its experiment kind (``work`` overrides them)
    (:func:`gtsweep.orchestration.skeleton.run_sweep` for the options)."""
    from gtsweep.core.config import plain
    from gtsweep.core.errors import BadInput

    work = options.pop("work", None)
    if work is None:
        name = (plain(cfg.get("experiment")) or {}).get("name")
        kind = EXPERIMENTS.get(name, None)
        if kind is None or kind.cells is None:
            sweeps = [e.name for e in EXPERIMENTS.values() if e.cells is not None]
            raise BadInput(f"experiment must be one of {', '.join(sweeps)}, got {name!r}")
        work = kind.cells
    return run_cells(cfg, output_dir, work, **options)


def combine_multirun(sweep_dir: str | Path, plots: bool = True, by: str | None = None, alpha: float = ALPHA):
    """``<sweep dir>/combined/`` of a multirun (:func:`gtsweep.report.combine.combine`), its report the one of the
    experiment kind its cells recorded; returns the files written."""
    def report_of(summaries: list[dict]):
        report = recorded_kind(summaries).report

        def write(means: list[dict], out_dir: Path, views: dict, scale) -> list[Path]:
            options = ReportOptions(plots=plots, views=lambda: views, by=by, alpha=alpha, scale=scale)
            return report(means, out_dir, options)[1]
        return write

    return combine(sweep_dir, report_of, alpha)
