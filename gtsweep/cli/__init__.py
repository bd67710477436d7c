"""The command line on top of every layer: ``python -m gtsweep``.

Before Hydra parses the command line, :mod:`gtsweep.cli.overrides` expands ``group=all``, checks every override
(one line and exit code 2 for a mistake) and, with ``resume=true``, reopens the newest earlier run; then the Hydra
application :mod:`gtsweep.cli.app` runs the job. Only the overrides are touched: Hydra's own flags work anywhere.
"""
from __future__ import annotations

import sys

from gtsweep.cli.overrides import fail, place, prepare, resume_args
from gtsweep.cli.search import parse
from gtsweep.core.configs import ignore_missing_dir
from gtsweep.core.errors import GtsweepError
from gtsweep.core.paths import DEFAULT_TUNED_ROOT


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    invocation = parse(args)
    if not invocation.passthrough:
        try:
            args = prepare(args)
            args = place(args, resume_args(args, invocation.multirun))
        except GtsweepError as e:
            fail(e)
    ignore_missing_dir(str(DEFAULT_TUNED_ROOT))
    sys.argv = [sys.argv[0], *args]
    from gtsweep.cli.app import hydra_main

    hydra_main()
