"""gtsweep's configs: the config groups of a sweep (detector, selector, descriptor, transform, dataset,
experiment) and, in a wheel, the presets of sweeps/ as the group ``sweeps``. Hydra reads them as ``pkg://gtsweep.conf``."""
