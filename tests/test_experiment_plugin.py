"""A new experiment kind is one folder, one YAML and one entry, registered once: a toy kind from outside the package
(``tests/toy_kind.py``: keypoints per image of each detector) declares its typed settings, its rows (metric,
headline, step, curves), its cells, report and summary in its :class:`~gtsweep.experiments.kinds.Experiment` entry
and nothing else. Hydra refuses a bad value of its settings; it runs end to end through ``python -m gtsweep``
(results.csv, MLflow child runs, its report), a ``-m`` multirun combined with its report, and ``python -m
gtsweep.report``, which picks its report by the kind the cells recorded."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import mlflow
import pandas as pd
import pytest
from hydra.core.config_store import ConfigStore

from gtsweep.cli import main as gtsweep_main
from gtsweep.evaluation import schema
from gtsweep.experiments.kinds import EXPERIMENTS, SETTINGS_GROUP
from gtsweep.experiments.report_command import main as report_main
from tests import toy_kind
from tests.sweep_helpers import tiny_overrides

NAME, METRIC = toy_kind.NAME, toy_kind.METRIC
PACKAGE = Path(__file__).resolve().parents[1] / "gtsweep"


@pytest.fixture
def toy(tmp_path):
    """The toy kind registered (its one call) and its one YAML in ``<tmp>/conf``; both gone afterwards."""
    declared = dict(schema.METRICS)
    EXPERIMENTS.register(toy_kind.ENTRY)
    conf = tmp_path / "conf"
    (conf / "experiment").mkdir(parents=True)
    (conf / "experiment" / f"{NAME}.yaml").write_text(toy_kind.YAML)
    yield conf
    EXPERIMENTS.unregister(NAME)
    assert NAME not in schema.ROWS and schema.METRICS == declared


def test_the_toy_kind_is_one_entry_registered_once(toy):
    assert not Path(toy_kind.__file__).resolve().is_relative_to(PACKAGE)  # nothing inside the package
    calls = {node.func.attr for node in ast.walk(ast.parse(Path(toy_kind.__file__).read_text()))
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)}
    assert not calls & {"register", "declare_rows", "store"}  # the module only declares; the fixture registers
    entry = EXPERIMENTS.get(NAME)
    assert (entry.headline, entry.step, entry.curves) == (METRIC, toy_kind.SCALE, (METRIC,))
    assert [m.name for m in entry.metrics] == [METRIC] and schema.headline(NAME) == METRIC
    assert schema.ROWS[NAME] is entry.rows and toy_kind.SCALE in schema.STEP_KEYS
    assert ConfigStore.instance().load(f"{SETTINGS_GROUP}/{NAME}.yaml") is not None  # typed for Hydra
    with pytest.raises(ValueError, match="registered twice"):
        EXPERIMENTS.register(toy_kind.ENTRY)
    assert schema.ROWS[NAME] is entry.rows


@pytest.mark.slow
@pytest.mark.parametrize("value, said", [("many", "experiment.min_size"), ("0", "experiment.min_size")])
def test_a_bad_toy_setting_is_refused_in_one_line(toy, tmp_path, monkeypatch, capsys, value, said):
    """A value of the wrong type is Hydra's own refusal (the typed settings); one out of range the entry's rule."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        gtsweep_main(["--config-dir", str(toy), f"experiment={NAME}", f"experiment.min_size={value}",
                      "mlflow.enabled=false", *tiny_overrides(tmp_path)])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip()
    assert said in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "outputs").exists() or not list((tmp_path / "outputs").glob("*/*/cells/*"))


@pytest.mark.slow
def test_a_toy_experiment_kind_runs_end_to_end(toy, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    common = ["--config-dir", str(toy), f"experiment={NAME}", "detector=[orb,fast]", "runner.backend=serial",
              f"mlflow.tracking_uri={uri}", *tiny_overrides(tmp_path)]
    gtsweep_main(common)
    assert "toy: 2 cells" in capsys.readouterr().out
    (run,) = (tmp_path / "outputs").glob("*/*")
    results = pd.read_csv(run / "results.csv")
    assert list(results["detector"]) == ["fast", "orb"] and (results["status"] == "ok").all()
    rows = pd.read_csv(next((run / "cells").glob("orb__*.csv")))
    assert sorted(rows[toy_kind.SCALE].unique()) == [0.5, 1.0]  # the step: each image at both scales
    orb = results.loc[results.detector == "orb", METRIC].item()
    assert orb == pytest.approx(rows.loc[rows[toy_kind.SCALE] == 1.0, METRIC].mean())  # the largest scale's
    summary = json.loads(next((run / "cells").glob("orb__*.json")).read_text())
    assert set(summary[f"by_{toy_kind.SCALE}"]) == {"0.5", "1.0"}
    mlflow.set_tracking_uri(uri)
    children = mlflow.search_runs(experiment_names=["gtsweep"], filter_string="params.detector = 'orb'")
    assert list(children[f"metrics.{METRIC}"]) == [orb]
    assert (run / "report" / "toy_counts.md").read_text().startswith("fast: ")
    (run / "report" / "toy_counts.md").unlink()
    assert report_main([str(run), "--no-plots"]) == 0
    assert (run / "report" / "toy_counts.md").exists()

    gtsweep_main(["-m", *common, "seed=0,1"])  # a multirun: combined with the toy's own report
    (combined,) = (tmp_path / "multirun").glob("*/*/combined")
    assert f"{METRIC} (keypoints): mean ± std (n)" in (combined / "summary.md").read_text()
    assert (combined / "report" / "toy_counts.md").read_text().splitlines() == \
        [f"fast: {results.loc[results.detector == 'fast', METRIC].item():.1f}", f"orb: {orb:.1f}"]
