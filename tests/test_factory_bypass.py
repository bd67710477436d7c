"""Configs cannot run code: the attacker's table.

Each entry is a config that would create ``PWNED`` in the working directory if gtsweep ran what it names: a
factory reached by walking attributes (``cv2.os.system``), a dunder, ``builtins``, ``importlib``, an
``attrgetter``-style name, a module reachable from numpy, Hydra or OmegaConf, an interpolation, gtsweep's own
``${gtsweep.new_dir:...}``, a plug-in or a Hydra ``_target_`` named in a file. Each is planted twice: as a tuned file
in ``./tuned`` (found in the working directory, no ``--config-dir``) and as a method of a ``--config-dir``.

The fast check runs the guards in process (the file check of the command line, then the composed config's factory
check); the slow one runs ``python -m gtsweep`` and asks for one line, exit 2, and nothing created: no marker, no
output directory, no MLflow store.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from gtsweep.core import factories, plugins
from gtsweep.core.configguard import check_config_files
from gtsweep.core.errors import BadInput
from sweep_helpers import cli_env, tiny_overrides

TOUCH = {"command": "touch PWNED"}
SHELL = {"args": "touch PWNED", "shell": True}
#: Imported, this module leaves the marker (the working directory is on ``python -m``'s sys.path).
EVIL_MODULE = "from pathlib import Path\nPath('PWNED').write_text('imported')\n\ndef create(**params):\n    pass\n"
#: A plug-in the user names on the command line: one registered constructor, one function that is not one.
PLUGIN = """from pathlib import Path
import cv2
from gtsweep.core.plugins import constructor

@constructor
def create(nfeatures=500):
    return cv2.ORB_create(nfeatures=nfeatures)

def touch(name='PWNED'):
    Path(name).write_text('called')
    return cv2.ORB_create()
"""
GLOBAL_CALLBACK = ("# @package _global_\nhydra:\n  callbacks:\n    evil:\n      _target_: subprocess.Popen\n"
                   "      args: touch PWNED\n      shell: true\n")
GLOBAL_PLUGINS = ("# @package _global_\nplugins: [evilmod]\ndetector:\n  evil:\n    factory: evilmod.create\n"
                  "    orientation: false\n")
GLOBAL_ENV = ("# @package _global_\nhydra:\n  job:\n    env_set:\n      GTSWEEP_PLUGINS: evilmod\n"
              "detector:\n  evil:\n    factory: evilmod.create\n    orientation: false\n")


@dataclass(frozen=True)
class Bypass:
    """One attempt: a factory (written as YAML text) with its params, or whole files for each place."""

    name: str
    factory: str = ""
    params: dict = field(default_factory=dict)
    tuned: str = ""  # the body of ./tuned/detector/tuned/fast.yaml, when not the factory's
    configdir: str = ""  # the body of myconf/detector/evil.yaml, when not the factory's
    args: tuple = ()
    env: tuple = ()

    def tuned_body(self) -> str:
        return self.tuned or (f"# @package detector\nfast:\n  factory: {self.factory}\n  orientation: false\n"
                              f"  params: {json.dumps(self.params)}\n")

    def configdir_body(self) -> str:
        return self.configdir or f"factory: {self.factory}\norientation: false\nparams: {json.dumps(self.params)}\n"


BYPASSES = [
    # attribute chains through a module to another module
    Bypass("cv2-os-system", "cv2.os.system", TOUCH),
    Bypass("gtsweep-module-os", "gtsweep.core.plugins.os.system", TOUCH),
    Bypass("gtsweep-module-subprocess", "gtsweep.tracking.watchdog.subprocess.Popen", SHELL),
    Bypass("cv2-sys-modules", "cv2.sys.modules.os.system", TOUCH),
    Bypass("xfeatures2d-walk", "cv2.xfeatures2d.SURF_create.__self__.os.system", TOUCH),
    # dunder names
    Bypass("dunder-self", "cv2.ORB_create.__self__.os.system", TOUCH),
    Bypass("dunder-import", "gtsweep.core.registry.importlib.__import__", {"name": "evilmod"}),
    # builtins and importlib
    Bypass("builtins-open", "builtins.open", {"file": "PWNED", "mode": "w"}),
    Bypass("importlib", "importlib.import_module", {"name": "evilmod"}),
    Bypass("cv2-importlib", "cv2.importlib.import_module", {"name": "evilmod"}),
    # operator.attrgetter-style and other spellings of a name
    Bypass("attrgetter", "operator.attrgetter", {"attr": "os.system"}),
    Bypass("colon-form", '"cv2:os.system"', TOUCH),
    Bypass("empty-component", '"cv2..os.system"', TOUCH),
    Bypass("padded", '" cv2.os.system "', TOUCH),
    # modules reachable from numpy, Hydra and OmegaConf
    Bypass("numpy-via-cv2", "cv2.numpy.savetxt", {"fname": "PWNED", "X": [1]}),
    Bypass("numpy-via-gtsweep", "gtsweep.stages.detect.np.save", {"file": "PWNED", "arr": [1]}),
    Bypass("hydra-call", "gtsweep.cli.app.hydra.utils.call", {"config": {"_target_": "os.system", **TOUCH}}),
    Bypass("omegaconf-save", "gtsweep.cli.app.OmegaConf.save", {"config": {"a": 1}, "f": "PWNED"}),
    # gtsweep functions that are not method constructors
    Bypass("gtsweep-new-dir", "gtsweep.core.rundirs.new_dir", {"base": "PWNED"}),
    Bypass("gtsweep-write", "gtsweep.core.atomic.write_atomically", {"path": "PWNED", "content": "x"}),
    # a plug-in the user named exposes only its registered constructors
    Bypass("plugin-walk", "goodplugin.os.system", TOUCH, args=("plugins=[goodplugin]",)),
    Bypass("plugin-unregistered", "goodplugin.touch", args=("plugins=[goodplugin]",)),
    # interpolations and gtsweep's own resolvers
    Bypass("env-interpolation", '"${oc.env:EVIL_FACTORY}"', TOUCH, env=(("EVIL_FACTORY", "cv2.os.system"),)),
    Bypass("new-dir-factory", '"${gtsweep.new_dir:PWNED}"'),
    Bypass("new-dir-param", tuned="# @package detector\nfast:\n  params: {threshold: '${gtsweep.new_dir:PWNED}'}\n",
           configdir="factory: cv2.FastFeatureDetector_create\norientation: false\n"
                     "params: {threshold: '${gtsweep.new_dir:PWNED}'}\n"),
    Bypass("python-tag", "!!python/object/apply:os.system ['touch PWNED']"),
    # plug-ins, Hydra's _target_ and the environment named in a file
    Bypass("plugins-in-file", tuned=GLOBAL_PLUGINS, configdir=GLOBAL_PLUGINS),
    Bypass("hydra-callback", tuned=GLOBAL_CALLBACK, configdir=GLOBAL_CALLBACK + "detector: {}\n"),
    Bypass("env-set", tuned=GLOBAL_ENV, configdir=GLOBAL_ENV),
    Bypass("tuned-defaults", tuned="# @package detector\ndefaults: [/detector/orb@_here_, _self_]\nfast:\n"
                                   "  params: {}\n", configdir="defaults: [evil2]\n"),
]
#: For ``tuned-defaults`` in a --config-dir: the file its defaults list loads.
EVIL2 = "factory: cv2.os.system\norientation: false\nparams: {command: touch PWNED}\n"
PLACES = ("tuned", "configdir")


def plant(root: Path, bypass: Bypass, place: str) -> list[str]:
    """The files of ``bypass`` in ``root`` (the working directory); the command line that selects them."""
    (root / "evilmod.py").write_text(EVIL_MODULE)
    (root / "plugin_dir").mkdir(exist_ok=True)
    (root / "plugin_dir" / "goodplugin.py").write_text(PLUGIN)
    if place == "tuned":
        file = root / "tuned/detector/tuned/fast.yaml"
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text(bypass.tuned_body())
        return ["detector=[tuned/fast]", *bypass.args]
    (root / "myconf/detector").mkdir(parents=True, exist_ok=True)
    (root / "myconf/detector/evil.yaml").write_text(bypass.configdir_body())
    (root / "myconf/detector/evil2.yaml").write_text(EVIL2)
    return ["--config-dir", str(root / "myconf"), "detector=[evil]", *bypass.args]


def created(root: Path) -> list[str]:
    """What a refused command left in ``root``: a marker, an output directory, an MLflow store."""
    return sorted(p.name for p in root.iterdir()
                  if p.name.startswith("PWNED") or p.name in ("outputs", "multirun", "mlflow.db", "mlruns"))


def test_the_table_is_an_attackers():
    assert len(BYPASSES) >= 20 and len({b.name for b in BYPASSES}) == len(BYPASSES)


def _composed(root: Path, place: str, bypass: Bypass):
    """The method nodes Hydra would compose from the planted file (the fast check's stand-in for composition)."""
    from omegaconf import OmegaConf

    if place == "tuned":
        return OmegaConf.create({"detector": OmegaConf.load(root / "tuned/detector/tuned/fast.yaml")})
    node = OmegaConf.load(root / "myconf/detector/evil.yaml")
    loaded = [OmegaConf.load(root / f"myconf/detector/{name}.yaml") for name in node.pop("defaults", [])]
    named = [a.partition("=")[2].strip("[]") for a in bypass.args if a.startswith("plugins=")]
    return OmegaConf.create({"detector": {"evil": OmegaConf.merge(*loaded, node)},
                             "plugins": node.get("plugins") or named})


@pytest.mark.parametrize("place", PLACES)
@pytest.mark.parametrize("bypass", BYPASSES, ids=lambda b: b.name)
def test_the_guards_refuse_each_bypass_in_process(bypass, place, tmp_path, monkeypatch):
    """The file check of the command line refuses the planted file, or else the composed config's factory check
    does (a factory resolved by exact name, interpolations unresolved); nothing is imported or created."""
    from gtsweep.core.rundirs import register_resolvers

    register_resolvers()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(plugins.ENV, "")
    monkeypatch.syspath_prepend(str(tmp_path / "plugin_dir"))
    monkeypatch.delitem(sys.modules, "goodplugin", raising=False)
    for key, value in bypass.env:
        monkeypatch.setenv(key, value)
    args = plant(tmp_path, bypass, place)
    entries = ["tuned://tuned", *([f"file://{tmp_path / 'myconf'}"] if place == "configdir" else [])]
    with pytest.raises(BadInput) as refused:
        check_config_files(entries)
        factories.check_composed(_composed(tmp_path, place, bypass), args)
    assert "\n" not in str(refused.value)
    assert created(tmp_path) == [] and "evilmod" not in sys.modules
    sys.modules.pop("goodplugin", None)


@pytest.mark.parametrize("bypass", [b for b in BYPASSES if b.factory], ids=lambda b: b.name)
def test_the_resolver_refuses_each_factory_by_name(bypass, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    import yaml

    path = yaml.safe_load(f"f: {bypass.factory}")["f"] if "!!" not in bypass.factory else bypass.factory
    with pytest.raises(BadInput, match="is refused"):
        factories.resolve(path, "detector 'evil'")
    assert created(tmp_path) == []


def run_gtsweep(root: Path, args: list[str], env: tuple = ()) -> subprocess.CompletedProcess:
    environment = {**cli_env(), **dict(env)}
    environment["PYTHONPATH"] = f"{environment['PYTHONPATH']}{os.pathsep}{root / 'plugin_dir'}"
    environment.pop(plugins.ENV, None)
    return subprocess.run([sys.executable, "-m", "gtsweep", *args], cwd=root, env=environment, capture_output=True,
                          text=True, timeout=300)


FAST = ["runner.backend=serial", "report.plots=false", "descriptor=[orb]", "transform=[incremental]"]


@pytest.mark.slow
@pytest.mark.parametrize("place", PLACES)
@pytest.mark.parametrize("bypass", BYPASSES, ids=lambda b: b.name)
def test_gtsweep_refuses_each_bypass_in_one_line_creating_nothing(bypass, place, tmp_path):
    args = plant(tmp_path, bypass, place)
    result = run_gtsweep(tmp_path, [*args, *tiny_overrides(tmp_path, *FAST)], bypass.env)
    assert result.returncode == 2, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert created(tmp_path) == []


@pytest.mark.slow
def test_a_plugin_named_on_the_command_line_gives_its_registered_constructor(tmp_path):
    """The legitimate counterpart of the plug-in entries: its registered constructor runs (and nothing else)."""
    plant(tmp_path, Bypass("x"), "configdir")
    (tmp_path / "myconf/detector/evil.yaml").write_text("factory: goodplugin.create\norientation: true\n"
                                                      "params: {nfeatures: 300}\n")
    args = ["--config-dir", str(tmp_path / "myconf"), "detector=[evil]", "plugins=[goodplugin]",
            "mlflow.enabled=false"]
    result = run_gtsweep(tmp_path, [*args, *tiny_overrides(tmp_path, *FAST)])
    assert result.returncode == 0, result.stderr
    assert not any(p.name.startswith("PWNED") for p in tmp_path.iterdir())


@pytest.mark.parametrize("declared", [False, True], ids=["package-method", "declared-in-config-dir"])
def test_a_tuned_file_as_optimize_writes_it_passes_the_guard(declared, tmp_path):
    """What ``experiment=optimize`` writes into ./tuned is accepted: a package method's parameters, or those of a
    method declared in a --config-dir (with that file's factory and capabilities repeated unchanged)."""
    from gtsweep.experiments.optimize.targets import Target
    from gtsweep.experiments.optimize.tuned_files import write_tuned

    name = "mine" if declared else "fast"
    node = {"params": {"threshold": 15}, "search_space": {"threshold": {"type": "int", "low": 3, "high": 60}}}
    if declared:
        node = {"factory": "cv2.FastFeatureDetector_create", "orientation": False, **node}
        (tmp_path / "myconf/detector").mkdir(parents=True)
        (tmp_path / "myconf/detector/mine.yaml").write_text(
            "factory: cv2.FastFeatureDetector_create\norientation: false\nparams: {threshold: 10}\n")
    target = Target("detector", name, name, None, node, {}, {}, {}, {})
    write_tuned(tmp_path / f"tuned/detector/tuned/{name}.yaml", target, {"threshold": 20}, ["a header"])
    check_config_files([f"tuned://{tmp_path / 'tuned'}", f"file://{tmp_path / 'myconf'}"])
    (tmp_path / "myconf/detector/mine.yaml").unlink(missing_ok=True)
    if declared:  # the method it tunes is gone: the tuned file names a factory nobody declared
        with pytest.raises(BadInput, match="is no method of the package"):
            check_config_files([f"tuned://{tmp_path / 'tuned'}", f"file://{tmp_path / 'myconf'}"])
