"""The experiment registry: the one place that knows an experiment kind. Each :class:`Experiment` entry declares
its settings (typed in Hydra's ConfigStore as ``schema/experiment/<name>``, their ranges checked before any work),
its rows (metrics, headline, step and curves: :class:`~gtsweep.evaluation.schema.Rows`), its cells on the sweep
skeleton (or a job of its own), its report, its terminal summary and how a multirun's jobs are combined.

A new kind is one folder (its cells, tasks, report), one ``conf/experiment/<name>.yaml`` (``name: <name>``, its
defaults list starting with ``/schema/experiment/<name>@_here_``) and one entry: ``EXPERIMENTS.register(...)``,
e.g. from a plug-in module. Registering it declares its rows in the metric schema; nothing else registers.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Mapping

from gtsweep.core.registry import Registry
from gtsweep.evaluation import schema
from gtsweep.experiments.localization.cells import LOCALIZATION
from gtsweep.experiments.localization.metrics import LOCALIZATION as LOCALIZATION_ROWS
from gtsweep.experiments.localization.report import format_localization
from gtsweep.experiments.localization.report import report as localization_report
from gtsweep.experiments.localization.settings import SETTINGS as LOCALIZATION_SETTINGS
from gtsweep.experiments.optimize.study_settings import SETTINGS as OPTIMIZE_SETTINGS
from gtsweep.experiments.pairs import metrics as pair_rows
from gtsweep.experiments.pairs import settings as pair_settings
from gtsweep.experiments.pairs.cells import PAIRS
from gtsweep.experiments.pairs.report import report as pair_report
from gtsweep.experiments.pairs.summary import format_outcome
from gtsweep.orchestration.schemas import SCHEMA_GROUP, typed_settings
from gtsweep.orchestration.skeleton import CellWork, SweepOutcome
from gtsweep.orchestration.skeleton import run_sweep as run_cells
from gtsweep.report.combine import combine
from gtsweep.report.output import ReportOptions
from gtsweep.report.scale import Scale
from gtsweep.report.tables import ALPHA, Table

#: Where an experiment's typed settings are stored in Hydra's ConfigStore (``schema/experiment/<name>``).
SETTINGS_GROUP = f"{SCHEMA_GROUP}/experiment"


#: ``report(summaries, out_dir, options) -> (tables, files)``.
Report = Callable[[list[dict], Path, ReportOptions], "tuple[list[Table], list[Path]]"]
#: ``summary(outcome, tables) -> str``: what the terminal shows at the end of a sweep.
Summary = Callable[[SweepOutcome, list[Table]], str]


@dataclass(frozen=True)
class Experiment:
    """One experiment kind. ``settings``: ``{key: rule}`` of its ``experiment.*`` settings; ``rows``: what its
    per-view rows hold (None for a kind without cells); ``cells``: its grid and evaluation on the sweep skeleton; or
    ``job``: a job of its own (``job(cfg, output_dir)``, e.g. parameter optimisation). ``report`` and ``summary``
    for a sweep's kind; ``budget_scale``: its report states the keypoint budget's scale (not only the success
    radius)."""

    name: str
    label: str
    settings: Mapping[str, object] = field(default_factory=dict)
    rows: schema.Rows | None = None
    cells: CellWork | None = None
    report: Report | None = None
    summary: Summary | None = None
    job: Callable[[Mapping, Path], None] | None = None
    budget_scale: bool = True

    @property
    def metrics(self) -> list[schema.Metric]:
        """The per-view columns of its rows and how a cell aggregates them, in schema order."""
        return schema.metrics_of(self.name)

    @property
    def headline(self) -> str:
        return self.rows.headline

    @property
    def step(self) -> str | None:
        return self.rows.step

    @property
    def curves(self) -> tuple[str, ...]:
        return self.rows.curves

    def combine(self, sweep_dir: str | Path, plots: bool = True, by: str | None = None,
                alpha: float = ALPHA) -> list[Path]:
        """``<sweep dir>/combined/`` of a multirun of this kind: one table across the jobs, and this kind's report
        of the repeats' means (:func:`gtsweep.report.combine.combine`); returns the files written."""
        def write(means: list[dict], out_dir: Path, views: dict, scale: Scale) -> list[Path]:
            options = ReportOptions(plots=plots, views=lambda: views, by=by, alpha=alpha, scale=scale)
            return self.report(means, out_dir, options)[1]

        return combine(sweep_dir, write, alpha)


class ExperimentRegistry(Registry[Experiment]):
    """The experiment kinds; registering one declares its rows in the metric schema and stores its typed settings
    in Hydra's ConfigStore."""

    def register(self, method: Experiment) -> Experiment:
        super().register(method)
        if method.rows is not None:
            try:
                schema.declare_rows(method.name, method.rows)
            except Exception:
                super().unregister(method.name)
                raise
        if method.settings:
            from hydra.core.config_store import ConfigStore

            ConfigStore.instance().store(group=SETTINGS_GROUP, name=method.name, node=typed_settings(
                method.settings))
        return method

    def unregister(self, name: str) -> None:
        super().unregister(name)
        schema.forget_rows(name)


def optimize_job(cfg: Mapping, output_dir: Path) -> None:
    """``experiment=optimize``'s job (its driver, and Optuna, imported only when it runs)."""
    from gtsweep.experiments.optimize.driver import main

    main(cfg, output_dir)


def _pairs(name: str, label: str, settings: dict, rows: schema.Rows) -> Experiment:
    return Experiment(name, label, settings, rows, PAIRS, pair_report, format_outcome)


EXPERIMENTS = ExperimentRegistry("experiment", [
    _pairs("detection", "keypoint detection (survey Tables 2, 3)", pair_settings.DETECTION, pair_rows.DETECTION),
    _pairs("matching", "detection and matching", pair_settings.MATCHING, pair_rows.MATCHING),
    _pairs("pose", "detection, matching and pose (survey Tables 4-7)", pair_settings.POSE, pair_rows.POSE),
    Experiment("localization", "localization against a map per floor", LOCALIZATION_SETTINGS, LOCALIZATION_ROWS,
               LOCALIZATION, localization_report, format_localization, budget_scale=False),
    Experiment("optimize", "parameter optimisation with Optuna", OPTIMIZE_SETTINGS, job=optimize_job),
], spec=Experiment)


def recorded_kind(summaries: list[dict]) -> Experiment:
    """The experiment kind the cells of a run recorded (a run has one kind)."""
    kinds = {schema.experiment_of(s) for s in summaries}
    reports = {EXPERIMENTS.get(kind).report for kind in kinds}  # an unknown kind: one line with the choices
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


def combine_multirun(sweep_dir: str | Path, plots: bool = True, by: str | None = None,
                     alpha: float = ALPHA) -> list[Path]:
    """``<sweep dir>/combined/`` of a multirun, combined by the experiment kind its cells recorded
    (:meth:`Experiment.combine`); returns the files written."""
    from gtsweep.report.combine import jobs_of
    from gtsweep.report.tables import load_summaries

    summaries = [s for job in jobs_of(Path(sweep_dir)) for s in load_summaries(job["dir"])]
    return recorded_kind(summaries).combine(sweep_dir, plots=plots, by=by, alpha=alpha)
