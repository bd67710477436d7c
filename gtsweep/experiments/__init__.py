"""Experiment kinds as plug-ins: the layer above the drivers (orchestration, optimize) and the report, below the
command line. :data:`gtsweep.experiments.kinds.EXPERIMENTS` holds one :class:`~gtsweep.experiments.kinds.
Experiment` per kind (detection, matching, pose, localization, optimize); the command line and ``python -m
gtsweep.report`` dispatch by a run's recorded kind through it.
"""
