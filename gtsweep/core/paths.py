"""Where gtsweep finds its configuration and keeps generated files.

The configs ship inside the package: a wheel holds ``conf/`` as the package ``gtsweep.conf`` and ``sweeps/`` as
its config group ``gtsweep.conf.sweeps`` (pyproject.toml), and Hydra finds them as ``pkg://gtsweep.conf``. A
source checkout (run in place or installed with ``pip install -e``) keeps ``conf/`` and ``sweeps/`` at the top of
the repository; :func:`mount_checkout_configs` makes it look like the wheel to ``importlib.resources`` (and so to
Hydra), before anything imports ``gtsweep.conf``.
"""
from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from importlib.resources.abc import Traversable
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent.parent
PROJECT_DIR = PACKAGE_DIR.parent
CONF_PACKAGE = "gtsweep.conf"
#: Generated data (rendered data sets, keypoint cache) lives here, relative to the working directory.
DEFAULT_CACHE_DIR = Path(".gtsweep_cache")
#: Where ``experiment=optimize`` writes tuned configs (``<root>/<group>/tuned/<name>.yaml``), relative to the
#: working directory; the primary config lists it on Hydra's search path before the package's configs.
DEFAULT_TUNED_ROOT = Path("tuned")


class MountedDir(Traversable):
    """A directory with other directories mounted in it by name: ``conf/`` with ``sweeps/`` as its ``sweeps``."""

    def __init__(self, root: Path, mounts: dict[str, Path]):
        self.root, self.mounts = root, mounts

    @property
    def name(self) -> str:
        return self.root.name

    def iterdir(self):
        yield from (p for p in self.root.iterdir() if p.name not in self.mounts)
        yield from self.mounts.values()

    def joinpath(self, *descendants):
        parts = [part for d in descendants for part in str(d).split("/") if part]
        if not parts:
            return self
        if parts[0] in self.mounts:
            return self.mounts[parts[0]].joinpath(*parts[1:])
        return self.root.joinpath(*parts)

    __truediv__ = joinpath

    def is_dir(self) -> bool:
        return True

    def is_file(self) -> bool:
        return False

    def exists(self) -> bool:
        return True

    def open(self, *args, **kwargs):
        raise IsADirectoryError(str(self.root))


class _MountedLoader(importlib.machinery.SourceFileLoader):
    """Loads a package from a directory; ``importlib.resources`` sees it with its mounts."""

    def __init__(self, fullname: str, path: str, files: Traversable):
        super().__init__(fullname, path)
        self.mounted = files

    def get_resource_reader(self, name):
        return self

    def files(self) -> Traversable:
        return self.mounted


def _load_package(name: str, directory: Path, files: Traversable | None = None):
    init = str(directory / "__init__.py")
    loader = _MountedLoader(name, init, files) if files is not None else None
    spec = importlib.util.spec_from_file_location(name, init, loader=loader,
                                                  submodule_search_locations=[str(directory)])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def mount_checkout_configs() -> None:
    """In a source checkout: ``gtsweep.conf`` = the repository's conf/ with sweeps/ mounted as its ``sweeps``."""
    conf, sweeps = PROJECT_DIR / "conf", PROJECT_DIR / "sweeps"
    if CONF_PACKAGE in sys.modules or (PACKAGE_DIR / "conf").is_dir() or not (conf / "__init__.py").is_file():
        return  # an installed wheel (gtsweep/conf), or already done
    _load_package(CONF_PACKAGE, conf, MountedDir(conf, {"sweeps": sweeps}))
    _load_package(f"{CONF_PACKAGE}.sweeps", sweeps)


mount_checkout_configs()
#: The package's own configs (groups detector, selector, ..., sweeps) as a directory tree.
CONF_DIR = Path(importlib.util.find_spec(CONF_PACKAGE).origin).parent
SWEEPS_DIR = Path(importlib.util.find_spec(f"{CONF_PACKAGE}.sweeps").origin).parent
