"""A config as ``python -m gtsweep`` composes it, for scripts, benchmarks and tests (:func:`compose_config`), and
what composing gtsweep's configs needs registered in a process (:func:`register_all`)."""
from __future__ import annotations

from pathlib import Path

from gtsweep.cli.search import PRIMARY_MODULE, PRIMARY_NAME, configs, user_searchpath, with_searchpath


def compose_config(overrides: list[str], config_dir: str | None = None):
    """The composed and checked config of one job of ``python -m gtsweep [--config-dir DIR] OVERRIDES``; a
    one-line :class:`~gtsweep.core.errors.GtsweepError` for a mistake."""
    from hydra import compose, initialize_config_module

    from gtsweep.cli.checks import check_job, forget_notes, translate

    register_all()
    forget_notes()
    overrides = with_searchpath(list(overrides))
    found = configs(["--config-dir", config_dir, *overrides] if config_dir else overrides)
    if config_dir:  # compose() has no --config-dir: the same place on the search path, via hydra.searchpath
        user = [f"file://{Path(config_dir).resolve()}", *(user_searchpath(overrides) or [])]
        overrides = [o for o in overrides if not o.lstrip("+").startswith("hydra.searchpath=")]
        overrides = with_searchpath([*overrides, f"hydra.searchpath=[{','.join(user)}]"])
    with initialize_config_module(config_module=PRIMARY_MODULE, version_base=None):
        try:
            cfg = compose(config_name=PRIMARY_NAME, overrides=overrides)
        except Exception as e:  # noqa: BLE001 - Hydra's and OmegaConf's errors, translated
            raise translate(e, overrides, found) from None
    check_job(cfg, overrides, found)
    return cfg


def register_all() -> None:
    """What composing gtsweep's configs needs in this process: its config sources, resolvers, schemas and
    sweeper; Hydra's warning about a missing ./tuned silenced."""
    from hydra.core.plugins import Plugins

    from gtsweep.cli.checks import runnable_options
    from gtsweep.core.paths import DEFAULT_TUNED_ROOT
    from gtsweep.core.rundirs import register_resolvers
    from gtsweep.core.searchpath import (choose_options_with, ignore_missing_dir, register_help_resolver,
                                         register_sources)
    from gtsweep.orchestration.schemas import register_schemas

    ignore_missing_dir(str(DEFAULT_TUNED_ROOT))
    choose_options_with(runnable_options)
    for register in (register_sources, register_resolvers, register_help_resolver, register_schemas):
        register()
    # after Hydra scanned its plugins (that re-imports its sweeper's module); stores the sweeper's config node too
    from hydra_plugins.gtsweep_sweeper import GtsweepSweeper

    Plugins.instance().register(GtsweepSweeper)  # also where Hydra's plugin discovery does not look (editable)
