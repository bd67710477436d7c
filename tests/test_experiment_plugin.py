"""A new experiment kind is one registry entry and one YAML: a toy kind (keypoints per image of each detector) runs
end to end through ``python -m gtsweep`` on the sweep skeleton: results.csv, MLflow child runs, its report, and
``python -m gtsweep.report`` picks its report by the kind the cells recorded."""
from __future__ import annotations

from pathlib import Path

import mlflow
import pandas as pd
import pytest

from gtsweep.cli import main as gtsweep_main
from gtsweep.core.config import plain
from gtsweep.evaluation import schema
from gtsweep.experiments.kinds import EXPERIMENTS, Experiment
from gtsweep.experiments.report_command import main as report_main
from gtsweep.experiments.pairs.grid import Cell, Grid
from gtsweep.orchestration.grid import resolve_group
from gtsweep.orchestration.tasks import RunStats
from gtsweep.experiments.pairs.cells import PAIRS
from gtsweep.orchestration.skeleton import CellWork
from gtsweep.stages.detect import detect
from tests.sweep_helpers import tiny_overrides

TOY = "toy_count"


def _grid(cfg) -> Grid:
    grid = Grid(experiment=plain(cfg["experiment"]), detectors=resolve_group(cfg, "detector"),
                selectors=resolve_group(cfg, "selector"), descriptors={}, transforms={"image": {}})
    grid.cells = [Cell(d, s, None, "image") for d in grid.detectors for s in grid.selectors]
    return grid


def _evaluate(grid, data, cells, runner_cfg, seed, cache_dir, finish, on_started) -> RunStats:
    on_started()
    images = data.dataset.images("synthetic")
    for cell in cells:
        rows = [{"view": i, "image": s.id, "texture": s.texture, "transform": "image",
                 "n_toy_keypoints": float(len(detect(s.load(), cell.detector,
                                                     **grid.detectors[cell.detector]["params"])))}
                for i, s in enumerate(images)]
        finish(cell, {"rows": pd.DataFrame(rows)})
    return RunStats()


def _report(summaries, out_dir: Path, options):
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "toy_counts.md"
    path.write_text("\n".join(f"{s['methods']['detector']}: {s['metrics']['n_toy_keypoints']:.1f}"
                              for s in summaries) + "\n")
    return [], [path]


@pytest.fixture
def toy_kind():
    schema.add_experiment(TOY, "n_toy_keypoints", schema.Metric("n_toy_keypoints", TOY, "keypoints",
                                                                "keypoints the detector finds per image"))
    EXPERIMENTS.register(Experiment(TOY, "keypoints per image", CellWork(_grid, PAIRS.load_data, _evaluate),
                                    _report, lambda outcome, tables: f"toy: {len(outcome.summaries)} cells"))
    yield
    EXPERIMENTS.unregister(TOY)
    schema.remove_experiment(TOY)


@pytest.mark.slow
def test_a_toy_experiment_kind_runs_end_to_end(toy_kind, tmp_path, monkeypatch, capsys):
    conf = tmp_path / "conf" / "experiment"
    conf.mkdir(parents=True)
    (conf / f"{TOY}.yaml").write_text(f"name: {TOY}\n")  # the one YAML
    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    gtsweep_main(["--config-dir", str(tmp_path / "conf"), f"experiment={TOY}", "detector=[orb,fast]",
                  "runner.backend=serial", f"mlflow.tracking_uri={uri}",
                  *tiny_overrides(tmp_path)])
    assert "toy: 2 cells" in capsys.readouterr().out
    (run,) = (tmp_path / "outputs").glob("*/*")
    results = pd.read_csv(run / "results.csv")
    assert list(results["detector"]) == ["fast", "orb"] and (results["status"] == "ok").all()
    assert (results["n_toy_keypoints"] > 0).all()
    mlflow.set_tracking_uri(uri)
    children = mlflow.search_runs(experiment_names=["gtsweep"], filter_string="params.detector = 'orb'")
    assert list(children["metrics.n_toy_keypoints"]) == list(results.loc[results.detector == "orb",
                                                                          "n_toy_keypoints"])
    assert (run / "report" / "toy_counts.md").read_text().startswith("fast: ")
    (run / "report" / "toy_counts.md").unlink()
    assert report_main([str(run), "--no-plots"]) == 0
    assert (run / "report" / "toy_counts.md").exists()
