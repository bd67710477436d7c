"""The command line on top of every layer, ``python -m gtsweep``: Hydra's own parser reads it and Hydra runs the
application :mod:`gtsweep.cli.app` on its seams (docs/architecture.md, "The command line")."""
from __future__ import annotations

import sys
from unittest import mock

from gtsweep.cli import completion, lifecycle
from gtsweep.cli.lifecycle import fail
from gtsweep.cli.overrides import register_all
from gtsweep.cli.search import PRIMARY, PRIMARY_NAME, configs, hydra_args, search_path
from gtsweep.core.configguard import check_config_files
from gtsweep.core.errors import GtsweepError
from gtsweep.core.interrupts import Interrupted, interruptible


def main(argv: list[str] | None = None) -> None:
    import yaml
    from hydra._internal.utils import _run_hydra, get_args_parser
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    args = list(sys.argv[1:] if argv is None else argv)
    if completion.handled(args):  # shell completion of a group's options, before the application loads
        return
    lifecycle.COMMAND[:] = args
    parsed = hydra_args(args)
    try:
        check_config_files(search_path(parsed))  # ./tuned and --config-dir hold data, never code
    except GtsweepError as e:
        fail(e)
    from gtsweep.cli.checks import forget_notes, note_left_out, translate  # the methods' registries: seconds

    register_all()
    forget_notes()
    # Ctrl-C while Hydra composes or imports: one line too; Hydra's errors raised (not printed) become one line
    with interruptible(), mock.patch.dict("os.environ", HYDRA_FULL_ERROR="1"):
        try:
            from gtsweep.cli.app import app

            _run_hydra(args=parsed, args_parser=get_args_parser(), task_function=app, config_path=PRIMARY,
                       config_name=PRIMARY_NAME)
            note_left_out()  # --cfg, --info: nothing ran, the line still says what all left out
        except (HydraException, OmegaConfBaseException, yaml.YAMLError, GtsweepError) as e:
            fail(translate(e, parsed.overrides, configs(args)))
        except ValueError as e:  # Hydra refuses a combination of its flags (e.g. -m with --cfg): one line
            if not str(e).startswith(("Only one of", "The --resolve flag")):
                raise
            fail(GtsweepError(str(e)))
        except Interrupted as e:
            lifecycle.exit_interrupted(e, "no cell has finished")
