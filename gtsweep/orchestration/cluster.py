"""Connecting to Ray: an embedded local instance by default, or an existing cluster by address."""
from __future__ import annotations

import logging

from gtsweep.core.errors import BadInput


def connect(runner_cfg: dict) -> None:
    """Start or join Ray once per process.

    ``address: local`` starts an embedded Ray (plain ``ray.init()`` would silently attach to a stale cluster
    recorded in /tmp/ray). ``auto`` joins the cluster this machine belongs to; ``host:port`` a remote head, which
    since Ray 2.59 needs its token: export ``RAY_AUTH_MODE=token`` and ``RAY_AUTH_TOKEN`` (see README).
    """
    import ray

    address = runner_cfg.get("address") or "local"
    if ray.is_initialized():
        current = ray.get_runtime_context().gcs_address
        if address in ("local", "auto") or address.split("://")[-1] == current:
            return
        ray.shutdown()  # connected elsewhere: the requested cluster wins
    options = {"include_dashboard": False, "logging_level": logging.WARNING, "log_to_driver": True}
    if runner_cfg.get("runtime_env"):
        options["runtime_env"] = dict(runner_cfg["runtime_env"])
    if address == "local":
        num_cpus = runner_cfg.get("num_cpus")
        if num_cpus is not None and (not isinstance(num_cpus, int) or num_cpus < 1):
            raise BadInput(f"runner.num_cpus must be a positive integer or null, got {num_cpus!r}")
        ray.init(address="local", num_cpus=num_cpus, **options)
        return
    try:
        ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, ValueError) as e:
        hint = "" if address == "auto" else " (a remote head needs RAY_AUTH_MODE=token and RAY_AUTH_TOKEN)"
        raise BadInput(f"cannot join the Ray cluster at '{address}': {str(e).splitlines()[0]}{hint}") from None
