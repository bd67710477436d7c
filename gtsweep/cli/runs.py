"""A run's output directory on Hydra's seams (docs/architecture.md): a single run's checked, claimed and, with
``resume=true``, reopened by the callback :class:`RunDirectory`; a multirun's by the sweeper (:func:`start_sweep_dir`).
"""
from __future__ import annotations

from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import open_dict

from gtsweep.cli.lifecycle import fail
from gtsweep.core.errors import GtsweepError, causes
from gtsweep.core.rundirs import check_writable, claim
from gtsweep.orchestration.resume_pick import command_key, earlier_run
from gtsweep.tracking.multirun import update_record


def claimed(config, key: str) -> Path:
    """Resolve and claim the run's directory (``hydra.sweep.dir`` in a multirun): writable, no other run in it."""
    try:
        directory = Path(str(config.hydra[key].dir))
    except Exception as e:  # the folder resolver could not create it: its one line
        raise next((c for c in causes(e) if isinstance(c, GtsweepError)), e) from None
    check_writable(directory)
    claim(directory)
    return directory


def reopen(config, multirun: bool) -> None:
    """With ``resume=true`` and no directory given: point ``hydra.run.dir`` / ``hydra.sweep.dir`` (and, for a
    multirun, every job's composition) at the newest earlier run of the same command."""
    key = "sweep" if multirun else "run"
    given = any(o.startswith(f"hydra.{key}.dir=") for o in config.hydra.overrides.hydra)
    if not config.get("resume") or given:
        return
    earlier = earlier_run(command_key(config.hydra.overrides.task), multirun)
    if earlier is not None:
        with open_dict(config):
            config.hydra[key].dir = str(earlier)
            config.hydra.overrides.hydra.append(f"hydra.{key}.dir={earlier}")


def start_sweep_dir(config) -> Path:
    """A checked multirun's directory: reopened when resuming, claimed, its command recorded."""
    reopen(config, multirun=True)
    sweep_dir = claimed(config, "sweep")
    update_record(sweep_dir, key=command_key(config.hydra.overrides.task))
    return sweep_dir


class RunDirectory(Callback):
    """A single run: its job checked, its directory reopened when resuming, then claimed."""

    def on_run_start(self, config, **kwargs) -> None:
        from gtsweep.cli.checks import check_job
        from gtsweep.core.searchpath import configs_of_sources

        try:
            check_job(config, list(config.hydra.overrides.task),
                      configs_of_sources(config.hydra.runtime.config_sources))
            reopen(config, multirun=False)
            claimed(config, "run")
        except GtsweepError as e:
            fail(e)
