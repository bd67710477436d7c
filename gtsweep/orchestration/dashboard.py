"""Whether Ray's dashboard can start here: checked before anything is created (``runner.dashboard=true``)."""
from __future__ import annotations

import importlib.util
from collections.abc import Mapping

from gtsweep.core.errors import BadInput


def check_dashboard(runner_cfg: Mapping) -> None:
    """``runner.dashboard=true`` with Ray's backend needs Ray's dashboard packages: a one-line BadInput otherwise
    (pre-flight: before any output directory or MLflow run exists)."""
    if runner_cfg.get("dashboard") and (runner_cfg.get("backend") or "ray") == "ray":
        missing = _dashboard_missing()
        if missing:
            raise BadInput(f"runner.dashboard=true needs Ray's dashboard: pip install 'ray[default]' ({missing})")


def _dashboard_missing() -> str | None:
    """Why Ray's dashboard cannot start (the minimal ``ray`` lacks its packages), else None."""
    try:
        from ray._private.utils import get_dashboard_dependency_error

        error = get_dashboard_dependency_error()
    except ImportError:  # a Ray without that helper: look for the dashboard's own package
        error = "No module named 'aiohttp'" if importlib.util.find_spec("aiohttp") is None else None
    return None if error is None else str(error)
