"""Experiment kinds as plug-ins: the layer above the engine (orchestration) and the report, below the command line.
Each kind is a wing of its own, ``gtsweep/experiments/<kind>/`` (pairs: detection, matching, pose; localization;
optimize), and :data:`gtsweep.experiments.kinds.EXPERIMENTS` holds one :class:`~gtsweep.experiments.kinds.
Experiment` entry per kind; the command line and ``python -m gtsweep.report`` dispatch by a run's recorded kind
through it. Importing any wing registers the built-in kinds (their rows in the metric schema, their typed settings
in Hydra's ConfigStore).
"""
from gtsweep.experiments.kinds import EXPERIMENTS

__all__ = ["EXPERIMENTS"]
