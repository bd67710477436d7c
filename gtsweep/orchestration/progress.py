"""What a sweep is doing, for the terminal and the job's log: each phase (render data set, start Ray, evaluate
cells, report) and a bar of finished cells.

The bar shows on an interactive terminal only (never in CI logs or pipes); every phase is a line of the job's log
(Hydra's ``<output dir>/<job name>.log``) either way. While it shows, every line for the terminal (warnings, Ray's
own lines and its workers' output, ``print``) is written above it by ``tqdm.write`` (:func:`lines_above_bar`), so
nothing is printed over the bar.
"""
from __future__ import annotations

import contextlib
import logging
import sys

from tqdm import tqdm
from tqdm.contrib import DummyTqdmFile

log = logging.getLogger(__name__)


class Progress:
    """``phase(name)`` as the sweep moves on, ``cell_done()`` per finished cell, ``close()`` at the end."""

    def __init__(self, enabled: bool = True, total: int | None = None):
        shown = enabled and sys.stderr.isatty()
        self.bar = tqdm(total=total, unit="cell", desc="gtsweep", file=sys.stderr, mininterval=0.5, leave=False,
                        disable=not shown, bar_format=_COUNTING if total is not None else _PHASE)
        self._redirect = contextlib.ExitStack()
        if shown:
            self._redirect.enter_context(lines_above_bar())

    def phase(self, name: str, total: int | None = None, done: int = 0) -> None:
        """Enter phase ``name`` (the bar's clock restarts); with ``total``, the bar counts cells (``done`` of them
        already)."""
        log.info("phase: %s", name)
        self.bar.reset(total=total)
        if total is not None:
            self.bar.update(done)
        self.bar.bar_format = _COUNTING if total is not None else _PHASE
        self.bar.set_description_str(name)  # set_description would append a second ": "

    def cell_done(self) -> None:
        self.bar.update(1)

    def close(self) -> None:
        self.bar.close()
        self._redirect.close()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


_COUNTING = "{desc}: {n_fmt}/{total_fmt} |{bar}| {elapsed}<{remaining}"
_PHASE = "{desc} ({elapsed})"


class _LineAboveBar(DummyTqdmFile):
    """A terminal stream whose whole lines go through ``tqdm.write``: the bar is cleared, the line written, the bar
    drawn again below it."""

    def write(self, text, nolock=False):
        with tqdm.get_lock():  # Ray prints its workers' lines from a thread of its own
            super().write(text, nolock=True)

    def finish(self) -> None:
        """Write what is left of an unfinished line."""
        if self._buf:
            self._wrapped.write(type(self._buf[0])().join(self._buf))
            self._buf = []

    # tqdm.write clears a bar on stderr before a line to stdout only when it finds both streams among sys.stdout and
    # sys.stderr, which are these wrappers while the bar shows: a wrapper equals its stream
    def __eq__(self, other):
        return self._wrapped == getattr(other, "_wrapped", other)

    def __hash__(self):
        return hash(self._wrapped)


@contextlib.contextmanager
def lines_above_bar():
    """While active: ``sys.stdout`` and ``sys.stderr`` (where ``print``, warnings and Ray write) and every logging
    handler that writes to them (Hydra's console handler) write their lines through ``tqdm.write``."""
    original = sys.stdout, sys.stderr
    streams = [_LineAboveBar(stream) for stream in original]
    loggers = [logging.root, *(v for v in logging.Logger.manager.loggerDict.values() if isinstance(v, logging.Logger))]
    handlers = [(handler, wrapper) for logger in loggers for handler in logger.handlers
                for stream, wrapper in zip(original, streams)
                if isinstance(handler, logging.StreamHandler) and handler.stream is stream]
    for handler, stream in handlers:
        handler.setStream(stream)
    sys.stdout, sys.stderr = streams
    try:
        yield
    finally:
        sys.stdout, sys.stderr = original
        for handler, stream in handlers:
            handler.setStream(stream._wrapped)
        for stream in streams:
            stream.finish()
