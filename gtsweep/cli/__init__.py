"""The command line on top of every layer: ``python -m gtsweep``.

Before Hydra parses the command line, :mod:`gtsweep.cli.overrides` expands ``group=all``, checks every override
(one line and exit code 2 for a mistake) and, with ``resume=true``, reopens the newest earlier run; then the Hydra
application :mod:`gtsweep.cli.app` runs the job.
"""
from __future__ import annotations

import sys

from gtsweep.cli import lifecycle
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

#: Flags that only print (help, config): no output directory needed.
PRINT_ONLY = ("-h", "--help", "--hydra-help", "-c", "--cfg", "-i", "--info", "--shell-completion", "-sc")


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    lifecycle.COMMAND = list(args)
    multirun = "-m" in args or "--multirun" in args
    try:
        args = expand_all(args)
        validate(args)
        args = force_add(args)
        args = place(args, [*resume_args(args, multirun), searchpath_override()])
        if not any(a in PRINT_ONLY for a in args):
            lifecycle.prepare_output(args, multirun)
    except GtsweepError as e:
        fail(e)
    lifecycle.register_resolvers()
    sys.argv = [sys.argv[0], *args]
    with lifecycle.interruptible():  # Ctrl-C while Hydra composes or imports: one line too
        try:
            from gtsweep.cli.app import hydra_main

            hydra_main()
        except lifecycle.Interrupted as e:
            lifecycle.exit_interrupted(e, "no cell has finished")
