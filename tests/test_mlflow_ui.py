"""Acceptance in a real browser: MLflow's UI (``mlflow server`` on 127.0.0.1) on the store of a small sweep run as
a user runs it (``python -m gtsweep``, with ``detector=[tuned/sift,orb]`` and rotation strengths), driven by
Playwright in headless Chromium. The address gtsweep prints opens the model-training view with the
"gtsweep: pairings" view; the cell runs show their methods as written (``tuned/sift``); a cell's artifacts hold
its per-strength figure.

Needs Debian's ``chromium`` (``make test`` installs it with apt-get when it can; by hand: ``apt-get install -y
chromium``) and the ``playwright`` package (the ``test`` extra); Playwright's own browser download is not used.
Without them the test skips and says so. Screenshots are left in the test's tmp_path (``pytest --basetemp=DIR``).
"""
from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys

import pytest

from gtsweep.tracking.views import VIEW_NAME, run_url
from sweep_helpers import TINY_DATASET, cli_env, mlflow_server

pytestmark = pytest.mark.slow

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def _chromium() -> str:
    found = next((path for path in map(shutil.which, BROWSERS) if path), None)
    if found is None:
        pytest.skip("no chromium on PATH: install Debian's with `apt-get install -y chromium` (make test does it "
                    "when run as root)")
    if importlib.util.find_spec("playwright") is None:
        pytest.skip("the playwright package is missing: pip install -e '.[test]'")
    return found


@pytest.fixture(scope="module")
def ui(tmp_path_factory, existing_store):
    """A sweep's store behind ``mlflow server``: (base address, the address gtsweep printed, store URI, tmp). The
    store exists before both (made once per session), so the server starts while the sweep runs."""
    chromium = _chromium()
    tmp = tmp_path_factory.mktemp("ui")
    uri = existing_store(tmp / "mlflow.db", tmp)
    sweep = subprocess.Popen(
        [sys.executable, "-m", "gtsweep", *TINY_DATASET, "dataset.n_incremental=0", "dataset.n_absolute=0",
         f"dataset.cache_dir={tmp}/data", f"cache.dir={tmp}/cache", "runner.progress=false", "runner.backend=serial",
         "experiment=matching", "detector=[tuned/sift,orb]", "descriptor=[brief]", "selector=[nms]",
         "transform=[rotation]", "transform.rotation.strengths=[0,90]", "report.plots=false",
         f"mlflow.tracking_uri={uri}"], cwd=tmp, env=cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    try:
        with mlflow_server(uri, tmp) as base:
            out, err = sweep.communicate(timeout=300)
            assert sweep.returncode == 0, err[-2000:]
            printed = next(line for line in out.splitlines() if line.startswith("MLflow: "))
            hint = printed.split("then open ")[-1].replace("http://127.0.0.1:5000", base)
            yield {"base": base, "hint": hint, "uri": uri, "tmp": tmp, "chromium": chromium}
    finally:
        if sweep.poll() is None:
            sweep.kill()
            sweep.communicate()


@pytest.fixture(scope="module")
def page(ui):
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=ui["chromium"], args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1920, "height": 1080})
        page.set_default_timeout(90_000)
        yield page
        browser.close()


def _cell_runs(ui) -> list:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(ui["uri"])
    experiment = client.get_experiment_by_name("gtsweep")
    return client.search_runs([experiment.experiment_id], "tags.`gtsweep.cell` LIKE '%'")


def test_printed_address_opens_the_training_view_with_the_pairings_view(ui, page):
    page.goto(ui["hint"])
    page.get_by_text(VIEW_NAME).first.wait_for()  # the saved view is applied
    page.get_by_text("tuned/sift").first.wait_for()  # a cell run's detector param, as the user wrote it
    page.get_by_text("orb", exact=True).first.wait_for()
    page.screenshot(path=str(ui["tmp"] / "runs.png"))
    nav = page.inner_text("body")
    assert "Models" in nav and "Evaluation runs" not in nav and "Judges" not in nav  # training, not GenAI layout
    headers = [h.strip() for h in page.get_by_role("columnheader").all_inner_texts()]
    assert {"detector", "descriptor", "precision"} <= set(headers) and "seed" not in headers, headers
    labels = page.get_by_text("Group: ", exact=False)
    tags = {run.data.tags["gtsweep.pairing"] for run in _cell_runs(ui)}
    assert sorted(label.removeprefix("Group: ").strip() for label in labels.all_inner_texts()) == sorted(tags)
    cut = [label.evaluate("e => e.scrollWidth > e.clientWidth") for label in labels.all()]
    assert not any(cut), "a group label is cut short in its column"


def test_cell_run_shows_its_params_and_its_strength_figure(ui, page):
    run = next(r for r in _cell_runs(ui) if r.data.params["detector"] == "tuned/sift")
    assert run.data.tags["gtsweep.method.detector"] == "sift"
    experiment = run.info.experiment_id
    page.goto(run_url(ui["base"], experiment, run.info.run_id))
    page.get_by_text("tuned/sift").first.wait_for()  # the Parameters table of the run's overview
    page.screenshot(path=str(ui["tmp"] / "run.png"))
    page.goto(run_url(ui["base"], experiment, run.info.run_id, "artifacts"))
    page.get_by_text("strength_curves.png").first.click()
    image = page.locator("img[alt='strength_curves.png']").first  # MLflow's preview of the artifact
    image.wait_for()
    page.wait_for_function("img => img.complete && img.naturalWidth > 0", arg=image.element_handle())
    width = image.evaluate("img => img.naturalWidth")
    page.screenshot(path=str(ui["tmp"] / "artifact.png"))
    assert width == 600  # the figure itself, drawn: one panel (matching: precision), 6 inches at 100 dpi
    assert "views.csv" in page.inner_text("body")
    (ui["tmp"] / "checked.json").write_text(json.dumps({"run": run.info.run_id, "figure_width": width}))
