"""The primary config of ``python -m gtsweep`` (``gtsweep.yaml``), alone in Hydra's main config directory."""
