"""The primary config of ``python -m gtsweep.datasets`` (``dataset_stats.yaml``)."""
