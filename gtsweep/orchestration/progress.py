"""What a sweep is doing, for the terminal and the job's log: each phase (render data set, start Ray, evaluate,
report) and a bar of finished cells.

The bar shows on an interactive terminal only (never in CI logs or pipes); every phase is a line of the job's log
(Hydra's ``<output dir>/<job name>.log``) either way.
"""
from __future__ import annotations

import logging
import sys

log = logging.getLogger(__name__)


class Progress:
    """``phase(name)`` as the sweep moves on, ``cell_done()`` per finished cell, ``close()`` at the end."""

    def __init__(self, enabled: bool = True, total: int | None = None):
        from tqdm import tqdm

        self.bar = tqdm(total=total, unit="cell", desc="gtsweep", file=sys.stderr, mininterval=0.5, leave=False,
                        disable=not (enabled and sys.stderr.isatty()), bar_format=_FORMAT)

    def phase(self, name: str, total: int | None = None, done: int = 0) -> None:
        """Enter phase ``name``; with ``total``, the bar counts cells (``done`` of them already)."""
        log.info("phase: %s", name)
        if total is not None:
            self.bar.reset(total=total)
            self.bar.update(done)
        self.bar.set_description(name)

    def cell_done(self) -> None:
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_FORMAT = "{desc}: {n_fmt}/{total_fmt} cells |{bar}| {elapsed}<{remaining}"
