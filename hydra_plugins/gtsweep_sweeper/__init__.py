"""gtsweep's Hydra sweeper, found by Hydra's plugin discovery (``hydra_plugins``) and selected by the primary
config (``override hydra/sweeper: gtsweep``). The work is in :mod:`gtsweep.cli.sweeper`."""
from dataclasses import dataclass

from hydra.core.config_store import ConfigStore

from gtsweep.cli.sweeper import CheckingSweeper


class GtsweepSweeper(CheckingSweeper):
    """Hydra's basic sweeper with ``group=glob(...)`` over the search path and every job checked first."""


@dataclass
class GtsweepSweeperConf:
    _target_: str = "hydra_plugins.gtsweep_sweeper.GtsweepSweeper"
    max_batch_size: int | None = None
    params: dict[str, str] | None = None


ConfigStore.instance().store(group="hydra/sweeper", name="gtsweep", node=GtsweepSweeperConf, provider="gtsweep")
