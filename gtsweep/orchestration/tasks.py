"""What every kind's work units share: a task's failure as a status, its timing, its cache counts, and the
counts of a whole run (:class:`RunStats`). The work units themselves are each kind's (``gtsweep.experiments.<kind>
.tasks``); an executor (:mod:`gtsweep.orchestration.executor`) runs them in-process or as Ray tasks. A task never
raises: an NA cell found at run time comes back as ``{"na": reason}``; anything else that stops it (a method not
available, a parameter OpenCV rejects, a bug) as ``{"error": reason}`` (:func:`failure`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

from gtsweep.core.errors import NotApplicable
from gtsweep.orchestration.cache import DenseMapCache, KeypointCache
from gtsweep.orchestration.executor import describe_error


@dataclass
class RunStats:
    """What a run did: cache hits and misses (a miss is one detector call), bad cache entries replaced, failed
    cache writes, the same for dense descriptor maps (a miss is one network run, e.g. XFeat's), and task counts."""

    cache_hits: int = 0
    cache_misses: int = 0
    cache_corrupt: int = 0
    cache_write_errors: int = 0
    dense_hits: int = 0
    dense_misses: int = 0
    dense_write_errors: int = 0
    detection_tasks: int = 0
    pairing_tasks: int = 0


def failure(error: Exception) -> dict:
    """A task's status for ``error``: ``{"na": reason}`` for a pairing the survey could not evaluate, else
    ``{"error": reason}`` (a one-line reason; a bug's also says where it was raised)."""
    if isinstance(error, NotApplicable):
        return {"na": error.reason}
    return {"error": describe_error(error)}


def timed(started: float, result: dict) -> dict:
    """``result`` with the task's wall-clock start and end (seconds since the epoch): a cell's compute time."""
    return {**result, "started": started, "ended": time.time()}


def counts(cache: KeypointCache) -> dict:
    """A task's cache counts for the driver: hits, misses, bad entries replaced, failed writes."""
    return {"hits": cache.hits, "misses": cache.misses, "corrupt": cache.corrupt, "write_errors": cache.write_errors}


def dense_counts(dense: DenseMapCache) -> dict:
    """A pairing task's dense-map counts for the driver (all 0 for a descriptor without a dense map)."""
    return {"hits": dense.hits, "misses": dense.misses, "write_errors": dense.write_errors}
