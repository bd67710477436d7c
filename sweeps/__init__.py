"""Sweep presets, one per survey table: the config group ``sweeps`` (``python -m gtsweep sweeps=smoke``)."""
