"""Ctrl-C and SIGTERM as an exception, :class:`Interrupted`, raised in the main thread by :func:`on_signal`.

An exception raised by a signal handler is lost when the handler happens to run inside a ``__del__`` or a weakref
callback (Python only prints it), so the signal is also recorded: the executors' result loops call
:func:`raise_pending` and stop there.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Iterator

from gtsweep.core.errors import causes

SIGNALS = (signal.SIGINT, signal.SIGTERM)
_pending: list[int] = []
_deferring = {"depth": 0, "arrived": []}  # inside deferred(): signals wait for the end of the block


class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived: stop, keep what is finished, say how to resume (not an ``Exception``, so that
    no ``except Exception`` on the way swallows it)."""

    def __init__(self, signum: int):
        self.signum = signum
        self.name = signal.Signals(signum).name
        super().__init__(f"interrupted by {self.name}")


_finished = {"done": False}  # the run's result is out (finished()): later signals change nothing


def finished() -> None:
    """The run's result is printed: SIGINT or SIGTERM from now on are ignored, so that the exit code stays the
    run's (a finished run never turns into "interrupted")."""
    _finished["done"] = True
    for s in SIGNALS:
        signal.signal(s, signal.SIG_IGN)


def on_signal(signum, frame) -> None:
    """The handler: record the signal, ignore later ones (the clean-up must finish), raise :class:`Interrupted`;
    nothing once the run has :func:`finished`."""
    if _finished["done"]:
        return
    for s in SIGNALS:
        signal.signal(s, signal.SIG_IGN)
    _pending.append(signum)
    if _deferring["depth"]:
        _deferring["arrived"].append(signum)
        return
    raise Interrupted(signum)


@contextlib.contextmanager
def deferred() -> Iterator[None]:
    """A block a signal must not cut in two (an MLflow run's records: a write interrupted half-way can leave the
    store locked, and the run could then not be marked KILLED): SIGINT/SIGTERM arriving inside raise
    :class:`Interrupted` when the block ends."""
    _deferring["depth"] += 1
    try:
        yield
    finally:
        _deferring["depth"] -= 1
    if not _deferring["depth"] and _deferring["arrived"]:
        raise Interrupted(_deferring["arrived"].pop(0))


def quiet_until_handled() -> None:
    """Until a run installs :func:`on_signal`: SIGINT or SIGTERM print one line and exit 130 / 143 at once (no
    ``KeyboardInterrupt`` traceback from the middle of an import; nothing has been written yet)."""
    for s in SIGNALS:
        signal.signal(s, _exit_quietly)


def _exit_quietly(signum, frame) -> None:
    if _finished["done"]:
        return
    os.write(2, f"gtsweep: interrupted by {signal.Signals(signum).name} while starting; nothing was run\n".encode())
    os._exit(128 + signum)


def raise_pending() -> None:
    """Raise :class:`Interrupted` if a signal arrived (its first exception may have been lost)."""
    if _pending:
        raise Interrupted(_pending[0])


def clear() -> None:
    _pending.clear()
    _deferring["arrived"].clear()


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`Interrupted` (once: later signals are ignored while it cleans up)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {s: signal.getsignal(s) for s in SIGNALS}
    for s in SIGNALS:
        signal.signal(s, on_signal)
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
        clear()


def interruption(error: BaseException) -> Interrupted | None:
    """The :class:`Interrupted` behind ``error``: Ray's compiled code turns an exception raised by a signal
    handler during ``ray.wait`` into a ``SystemError`` caused by it."""
    return next((e for e in causes(error) if isinstance(e, Interrupted)), None)
