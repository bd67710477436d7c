"""The command line on top of every layer: ``python -m gtsweep``.

Before Hydra parses the command line, :mod:`gtsweep.cli.overrides` expands ``group=all``, checks every override
(one line and exit code 2 for a mistake) and, with ``resume=true``, reopens the newest earlier run; then the Hydra
application :mod:`gtsweep.cli.app` runs the job.
"""
from __future__ import annotations

import sys

from gtsweep.cli.overrides import (
    expand_all,
    fail,
    force_add,
    place,
    resume_args,
    searchpath_override,
    validate,
)
from gtsweep.core.errors import GtsweepError


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    multirun = "-m" in args or "--multirun" in args
    try:
        args = expand_all(args)
        validate(args)
        args = force_add(args)
        args = place(args, [*resume_args(args, multirun), searchpath_override()])
    except GtsweepError as e:
        fail(e)
    sys.argv = [sys.argv[0], *args]
    from gtsweep.cli.app import hydra_main

    hydra_main()
