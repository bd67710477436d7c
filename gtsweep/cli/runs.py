"""A run's output directory on Hydra's seams: checked, claimed and, with ``resume=true``, reopened.

- A single run: the callback :class:`RunDirectory` (``hydra.callbacks.run`` in conf/config.yaml) checks the job
  (:func:`gtsweep.cli.checks.check_job`), then points ``hydra.run.dir`` at the newest earlier run of the same
  command when resuming, and claims the directory before Hydra writes into it.
- A multirun: the sweeper (:mod:`gtsweep.cli.sweeper`) does the same for ``hydra.sweep.dir`` once every job is
  checked (:func:`start_sweep_dir`); a resumed multirun's jobs find their earlier directories below it.

"The same command" is its overrides without ``resume`` (:func:`command_key`), recorded in ``sweep.json`` of a
run and of each job of a multirun (the multirun's key, kept in its ``multirun.json``).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

from hydra.experimental.callback import Callback
from omegaconf import open_dict

from gtsweep.cli.multirun import MULTIRUN_RECORD
from gtsweep.core.errors import GtsweepError

SWEEP_RECORD = "sweep.json"


def command_key(overrides) -> str:
    """What identifies "the same command" for resume: its overrides, without resume and hydra settings."""
    kept = sorted(o for o in overrides if not o.startswith(("resume=", "hydra.")))
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()[:16]


def earlier_run(key: str, multirun: bool, root: Path | None = None) -> Path | None:
    """The newest output directory (a multirun's, for ``multirun``) of an earlier command with ``key`` that holds a
    run (:func:`gtsweep.orchestration.resume_pick.pick`, which says which and why)."""
    from gtsweep.orchestration.resume_pick import pick

    pattern = f"multirun/*/*/*/{SWEEP_RECORD}" if multirun else f"outputs/*/*/{SWEEP_RECORD}"
    picked = pick(list((root or Path.cwd()).glob(pattern)), key)
    print(f"gtsweep: {picked.why}", file=sys.stderr)
    if picked.directory is None:
        return None
    return picked.directory.parent if multirun else picked.directory


def claimed(config, key: str) -> Path:
    """Resolve and claim the run's directory (``hydra.sweep.dir`` in a multirun): writable, no other run in it."""
    from gtsweep.core.errors import causes
    from gtsweep.cli.lifecycle import check_writable, claim

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
    path = sweep_dir / MULTIRUN_RECORD
    record = json.loads(path.read_text()) if path.exists() else {}
    path.write_text(json.dumps({**record, "key": command_key(config.hydra.overrides.task)}))
    return sweep_dir


class RunDirectory(Callback):
    """A single run: its job checked, its directory reopened when resuming, then claimed."""

    def on_run_start(self, config, **kwargs) -> None:
        from gtsweep.cli.checks import check_job
        from gtsweep.cli.lifecycle import fail
        from gtsweep.core.searchpath import configs_of_sources

        try:
            check_job(config, list(config.hydra.overrides.task),
                      configs_of_sources(config.hydra.runtime.config_sources))
            reopen(config, multirun=False)
            claimed(config, "run")
        except GtsweepError as e:
            fail(e)
