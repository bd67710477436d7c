"""The package as pip builds it: a wheel installed outside the source tree (without its dependencies, into a target
folder) runs a preset, its help, ``--cfg job`` and the report from an unrelated directory; and ``-m seed=0,1`` writes
one combined table with both seeds."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from sweep_helpers import run_cli

from gtsweep.core.paths import PROJECT_DIR

SMALL = ["dataset.textures=[gravel,wood]", "dataset.view_size=[320,240]", "dataset.n_incremental=1",
         "dataset.n_absolute=1", "dataset.n_synthetic=1", "dataset.n_optimisation=1", "runner.backend=serial",
         "mlflow.enabled=false", "runner.progress=false"]


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    """``pip wheel --no-deps`` of this checkout, installed with ``pip install --no-deps --target``."""
    tmp = tmp_path_factory.mktemp("wheel")
    source = tmp / "source"  # setuptools builds in the source tree (build/, *.egg-info): a copy of it
    shutil.copytree(PROJECT_DIR, source, ignore=shutil.ignore_patterns(
        ".git", ".venv", "outputs", "multirun", ".gtsweep_cache", "mlruns", "mlflow.db", "build", "*.egg-info",
        "__pycache__", "tests", "benchmarks", "docs"))
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run([*pip, "wheel", "--no-deps", "-w", str(tmp / "dist"), str(source)], check=True,
                   capture_output=True, timeout=600, cwd=tmp)
    (wheel,) = (tmp / "dist").glob("gtsweep-*.whl")
    subprocess.run([*pip, "install", "--no-deps", "--target", str(tmp / "site"), str(wheel)], check=True,
                   capture_output=True, timeout=600)
    return tmp / "site"


def _run(site: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_wheel_runs_a_preset_from_an_unrelated_directory(installed, tmp_path):
    where = _run(installed, tmp_path, "-c", "import gtsweep.conf, gtsweep; print(gtsweep.__file__)")
    assert where.stdout.strip() == str(installed / "gtsweep" / "__init__.py"), where.stderr
    done = _run(installed, tmp_path, "-m", "gtsweep", "sweeps=smoke", *SMALL)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Survey Table 4: pose success on incremental pairs" in done.stdout
    (output,) = tmp_path.glob("outputs/*/*/results.csv")
    assert len(pd.read_csv(output)) == 18  # the smoke preset's 3 x 3 x 2 cells, tuned detectors from the wheel
    assert (output.parent / "app.log").read_text().count("phase: evaluate") == 1
    report = _run(installed, tmp_path, "-m", "gtsweep.report", str(output.parent), "--no-plots")
    assert report.returncode == 0 and "Survey Table 5" in report.stdout, report.stderr
    shown = _run(installed, tmp_path, "-m", "gtsweep", "sweeps=smoke", "detector=[orb]", "--cfg", "job")
    assert shown.returncode == 0 and "orb:" in shown.stdout and "sift:" not in shown.stdout.split("selector:")[0]
    helped = _run(installed, tmp_path, "-m", "gtsweep", "--help")
    assert helped.returncode == 0 and "sweeps: smoke," in helped.stdout
    datasets = _run(installed, tmp_path, "-m", "gtsweep.datasets", "--help")
    assert datasets.returncode == 0 and "dataset: csv, folder" in datasets.stdout


@pytest.mark.slow
def test_a_multirun_over_seeds_writes_one_combined_table(tmp_path):
    done = run_cli(["-m", "seed=0,1", "detector=[orb]", "descriptor=[orb]", "transform=[incremental]", *SMALL,
                    f"hydra.sweep.dir={tmp_path}/multi"], tmp_path)
    assert done.returncode == 0, done.stderr[-3000:]
    rows = pd.read_csv(tmp_path / "multi" / "combined" / "all_results.csv")
    assert sorted(rows["seed"]) == [0, 1] and set(rows["detector"]) == {"orb"}
    summary = pd.read_csv(tmp_path / "multi" / "combined" / "summary.csv")
    assert list(summary["n"]) == [2] and "pose_success_std" in summary
    assert "multirun: jobs combined in" in done.stdout
