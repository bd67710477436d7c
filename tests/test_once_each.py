"""Each constant written once: the survey's matcher and estimator, the method groups (a result's method columns),
the names of what a run writes in its output directory. A second spelling of one of them in the package fails here."""
from __future__ import annotations

import ast
from pathlib import Path

from gtsweep.core import rundirs
from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.paths import DEFAULT_CACHE_DIR
from gtsweep.orchestration.grid import REGISTRIES, SURVEY_METHODS
from gtsweep.stages.match import SURVEY_MATCHER
from gtsweep.stages.pose import SURVEY_ESTIMATOR
from sweep_helpers import compose_config

PACKAGE = Path(__file__).resolve().parents[1] / "gtsweep"
#: Where a literal may stand besides its definition: the OpenCV estimator named "ransac" (not the survey's), and
#: the optimiser's pose settings, which the move of the optimiser into its experiment's folder rebuilds from the
#: matcher and estimator groups.
ALSO = {"bf_ratio": {"study_settings.py"}, "ransac": {"pose.py", "study_settings.py"},
        "run.json": {"skeleton.py", "summary.py"}}
OUTPUT_NAMES = [rundirs.RESULTS, rundirs.RUN_RECORD, rundirs.PARENT_RECORD, rundirs.SWEEP_RECORD,
                rundirs.MULTIRUN_RECORD]


def _literals() -> list[tuple[str, object]]:
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                found.append((path.name, node.value))
            elif isinstance(node, (ast.Tuple, ast.List)) and all(isinstance(e, ast.Constant) for e in node.elts):
                found.append((path.name, tuple(e.value for e in node.elts)))
    return found


def test_the_survey_methods_are_written_once():
    assert SURVEY_METHODS == {"matcher": SURVEY_MATCHER, "estimator": SURVEY_ESTIMATOR}
    cfg = compose_config([])
    assert (list(cfg.matcher), list(cfg.estimator)) == ([SURVEY_MATCHER], [SURVEY_ESTIMATOR])  # conf/config.yaml
    literals = _literals()
    for name, defined_in in ((SURVEY_MATCHER, "match.py"), (SURVEY_ESTIMATOR, "pose.py")):
        places = {file for file, value in literals if value == name}
        assert places <= {defined_in, *ALSO[name]}, name


def test_the_method_groups_are_written_once():
    assert tuple(REGISTRIES) == METHOD_GROUPS
    places = [file for file, value in _literals() if value == METHOD_GROUPS]
    assert places == ["config.py"]


def test_the_output_names_are_written_once():
    literals = _literals()
    for name in OUTPUT_NAMES:
        places = sorted(file for file, value in literals if value == name)
        assert [p for p in places if p not in ALSO.get(name, ())] == ["rundirs.py"], name


def test_the_configs_keep_their_files_in_the_cache_folder():
    """The cache folder is named once in code (core.paths); the configs' cache settings lie inside it."""
    cfg = compose_config([])
    survey = compose_config(["dataset=survey"])
    for setting in (cfg.cache.dir, cfg.dataset.cache_dir, survey.dataset.cache_dir):
        assert Path(setting).parts[0] == str(DEFAULT_CACHE_DIR)
    assert [file for file, value in _literals() if value == str(DEFAULT_CACHE_DIR)] == ["paths.py"]


def test_a_run_settings_default_is_the_primary_configs():
    """A caller that gives only some run settings (a script, a library call) gets conf/config.yaml's defaults."""
    from gtsweep.orchestration.settings import default

    cfg = compose_config([])
    for key in ("runner.backend", "runner.opencv_threads", "runner.connect_timeout_s", "runner.gpus_per_task",
                "runner.describe_together", "runner.dashboard", "cache.enabled", "mlflow.timeout_s",
                "mlflow.experiment"):
        section, name = key.split(".")
        assert default(key) == cfg[section][name], key
