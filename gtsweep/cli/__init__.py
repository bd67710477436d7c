"""The command line on top of every layer: ``python -m gtsweep``.

Before Hydra runs the job, :mod:`gtsweep.cli.overrides` expands ``group=all``, has Hydra compose every job once
(:mod:`gtsweep.cli.preflight`: one line and exit code 2 for a mistake) and, with ``resume=true``, reopens the
newest earlier run; the output directory is checked (writable, not in use by another run) before Hydra writes
anything; then the Hydra application :mod:`gtsweep.cli.app` runs the job. Only the overrides are touched: Hydra's
own flags work anywhere.
"""
from __future__ import annotations

import sys

from gtsweep.cli import completion, lifecycle
from gtsweep.cli.overrides import fail, place, prepare, resume_args
from gtsweep.cli.search import parse, search_path
from gtsweep.core.errors import GtsweepError
from gtsweep.core.paths import DEFAULT_TUNED_ROOT
from gtsweep.core.configguard import check_config_files
from gtsweep.core.searchpath import ignore_missing_dir, register_sources

#: Flags that only print (help, config): no output directory needed.
PRINT_ONLY = ("-h", "--help", "--hydra-help", "-c", "--cfg", "-i", "--info", "--shell-completion", "-sc")


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if completion.handled(args):  # shell completion of a group's options, before the application loads
        return
    invocation = parse(args)
    if not invocation.passthrough:
        try:
            check_config_files(search_path(args))  # ./tuned and --config-dir hold data, never code
            args = prepare(args)
            args = place(args, resume_args(args, invocation.multirun))
            if not any(a in PRINT_ONLY for a in args):
                lifecycle.prepare_output(args, invocation.multirun)
        except GtsweepError as e:
            fail(e)
    ignore_missing_dir(str(DEFAULT_TUNED_ROOT))
    lifecycle.register_resolvers()
    register_sources()
    sys.argv = [sys.argv[0], *args]
    with lifecycle.interruptible():  # Ctrl-C while Hydra composes or imports: one line too
        try:
            from gtsweep.cli.app import hydra_main

            hydra_main()
        except ValueError as e:  # Hydra refuses a combination of its flags (e.g. -m with --cfg): one line
            if not str(e).startswith("Only one of"):
                raise
            fail(GtsweepError(str(e)))
        except lifecycle.Interrupted as e:
            lifecycle.exit_interrupted(e, "no cell has finished")
