"""Configuration nodes as plain data, and stable hashes of them."""
from __future__ import annotations

import hashlib
import json
from typing import Any

from gtsweep.core.errors import BadInput

#: The config groups that hold methods, a grid dimension each (only these have tuned files), in the order of a
#: result's method columns.
METHOD_GROUPS = ("detector", "selector", "descriptor", "transform", "matcher", "estimator")


def plain(node, where: str = "") -> Any:
    """A config node as plain Python containers, interpolations resolved; other values are returned as they are.

    A missing mandatory value (``???``) raises a one-line :class:`BadInput` naming the key (``where`` is the
    node's own dotted path, e.g. ``dataset``).
    """
    from omegaconf import DictConfig, OmegaConf
    from omegaconf.errors import MissingMandatoryValue

    if not (isinstance(node, DictConfig) or OmegaConf.is_list(node)):
        return node
    try:
        return OmegaConf.to_container(node, resolve=True, throw_on_missing=True)
    except MissingMandatoryValue as error:
        key = str(getattr(error, "full_key", "") or "root")
        key = key if not where or key.startswith(f"{where}.") else f"{where}.{key}"
        raise BadInput(f"{key} is required (give it on the command line, e.g. {key}=...)") from None


def config_hash(value) -> str:
    """A short stable hash of a JSON-able value."""
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]
