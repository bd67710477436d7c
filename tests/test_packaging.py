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

from gtsweep.core.paths import PROJECT_DIR
from sweep_helpers import run_cli

SMALL = ["dataset.textures=[gravel,wood]", "dataset.view_size=[320,240]", "dataset.n_incremental=1",
         "dataset.n_absolute=1", "dataset.n_synthetic=1", "dataset.n_optimisation=1", "runner.backend=serial",
         "mlflow.enabled=false", "runner.progress=false"]


LICENCES = ("LICENSE", "gtsweep/models/LICENSE-xfeat", "gtsweep/models/NOTICE-xfeat")


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> tuple[Path, str]:
    """``python -m build``: the sdist of this checkout, then the wheel built from that sdist (so the sdist holds all
    the wheel needs); returns the dist folder and the build's output."""
    tmp = tmp_path_factory.mktemp("wheel")
    source = tmp / "source"  # setuptools builds in the source tree (build/, *.egg-info): a copy of it
    shutil.copytree(PROJECT_DIR, source, ignore=shutil.ignore_patterns(
        ".git", ".venv", "outputs", "multirun", ".gtsweep_cache", "mlruns", "mlflow.db", "build", "*.egg-info",
        "__pycache__", "tests", "benchmarks", "docs", "dist"))
    # PYTHONDONTWRITEBYTECODE makes setuptools warn that it skips byte-compiling: not a warning about the package
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    done = subprocess.run([sys.executable, "-m", "build", "--sdist", "--wheel", "-o", str(tmp / "dist"), str(source)],
                          capture_output=True, text=True, timeout=900, cwd=tmp, env=env)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return tmp / "dist", done.stdout + done.stderr


@pytest.fixture(scope="module")
def installed(built, tmp_path_factory) -> Path:
    """The wheel, installed with ``pip install --no-deps --target``."""
    (wheel,) = built[0].glob("gtsweep-*.whl")
    site = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", "-q", "install", "--no-deps",
                    "--target", str(site), str(wheel)], check=True, capture_output=True, timeout=600)
    return site


@pytest.mark.slow
def test_the_build_warns_nothing_and_ships_the_licences_and_the_command(built):
    import tarfile
    import zipfile

    dist, log = built
    assert "Package would be ignored" not in log and "warning" not in log.lower(), log[-3000:]
    (sdist,), (wheel,) = dist.glob("gtsweep-*.tar.gz"), dist.glob("gtsweep-*.whl")
    with tarfile.open(sdist) as archive:
        names = {name.split("/", 1)[1] for name in archive.getnames() if "/" in name}
    assert set(LICENCES) <= names
    with zipfile.ZipFile(wheel) as archive:
        names = set(archive.namelist())
        entry_points = archive.read("gtsweep-0.1.0.dist-info/entry_points.txt").decode()
        licence = archive.read("gtsweep-0.1.0.dist-info/licenses/LICENSE").decode()
    assert {f"gtsweep-0.1.0.dist-info/licenses/{name}" for name in LICENCES} <= names
    assert {"gtsweep/models/LICENSE-xfeat", "gtsweep/models/NOTICE-xfeat", "gtsweep/models/xfeat.onnx"} <= names
    assert "Apache License" in licence and "Version 2.0, January 2004" in licence
    assert "[console_scripts]\ngtsweep = gtsweep.__main__:run" in entry_points
    assert {"gtsweep/conf/detector/tuned/sift.yaml", "gtsweep/conf/sweeps/smoke.yaml"} <= names


def _run(site: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


@pytest.mark.slow
def test_the_wheel_runs_a_preset_from_an_unrelated_directory(installed, tmp_path):
    where = _run(installed, tmp_path, "-c", "import gtsweep.conf, gtsweep; print(gtsweep.__file__)")
    assert where.stdout.strip() == str(installed / "gtsweep" / "__init__.py"), where.stderr
    done = _run(installed, tmp_path, "-m", "gtsweep", "sweeps=smoke", *SMALL)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Survey Table 4: pose success (share of pairs) on incremental pairs" in done.stdout
    (output,) = tmp_path.glob("outputs/*/*/results.csv")
    assert len(pd.read_csv(output)) == 18  # the smoke preset's 3 x 3 x 2 cells, tuned detectors from the wheel
    assert (output.parent / "app.log").read_text().count("phase: evaluate") == 1
    report = _run(installed, tmp_path, "-m", "gtsweep.report", str(output.parent), "--no-plots")
    assert report.returncode == 0 and "Survey Table 5" in report.stdout, report.stderr
    shown = _run(installed, tmp_path, "-m", "gtsweep", "sweeps=smoke", "detector=[orb]", "--cfg", "job")
    assert shown.returncode == 0 and "orb:" in shown.stdout and "sift:" not in shown.stdout.split("selector:")[0]
    helped = _run(installed, tmp_path, "-m", "gtsweep", "--help")
    assert helped.returncode == 0 and "sweeps: smoke," in helped.stdout
    command = subprocess.run([str(installed / "bin" / "gtsweep"), "--help"], cwd=tmp_path, capture_output=True,
                             text=True, timeout=600, env={**os.environ, "PYTHONPATH": str(installed)})
    assert command.returncode == 0 and command.stdout == helped.stdout  # the console script is python -m gtsweep
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
