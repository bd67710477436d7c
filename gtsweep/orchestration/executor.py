"""Where tasks run: one interface for the sweep and the optimiser, in one process (``serial``) or on Ray.

A driver :meth:`~SerialExecutor.put`\\ s large inputs once, :meth:`~SerialExecutor.submit`\\ s plain functions
(the handles a submit returns can be passed, as top-level arguments, to later submits), and reads
``(tag, result)`` from :meth:`~SerialExecutor.results` as the tagged tasks finish. A task that crashes gives
``{"error": reason}``, never an exception in the driver. Tasks are pure functions of their arguments, so the same
inputs give bit-identical results on either backend.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import os
import signal
import sys
import threading
import traceback
from collections import deque
from typing import Any, Callable, Iterator, Mapping

from gtsweep.core import plugins
from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.interrupts import raise_pending
from gtsweep.orchestration.cluster import (address_source, check_address, cluster_address, record_cluster,
                                           record_serial, this_machines_cluster)
from gtsweep.orchestration.dashboard import check_dashboard
from gtsweep.orchestration.settings import default

BACKENDS = ("ray", "serial")
log = logging.getLogger(__name__)


def backend(runner_cfg: Mapping) -> str:
    """``runner.backend``, checked: ``ray`` or ``serial``."""
    name = runner_cfg.get("backend", default("runner.backend"))
    if name not in BACKENDS:
        raise BadInput(f"runner.backend must be one of {', '.join(BACKENDS)}, got {name!r}")
    return name


def make_executor(runner_cfg: Mapping, retries: int = 3):
    """The executor ``runner`` asks for; Ray is started or joined here. ``retries``: Ray's re-runs of a task
    whose worker died (0 for work that may itself kill the worker, e.g. an optimiser trial)."""
    if backend(runner_cfg) == "serial":
        record_serial()
        return SerialExecutor()
    return RayExecutor(runner_cfg, retries)


def describe_error(error: BaseException) -> str:
    """A failure in one line: a :class:`GtsweepError`'s message as it is; anything else with its type and the
    line that raised it."""
    message = " ".join(str(error).split())  # OpenCV's messages span lines
    if isinstance(error, GtsweepError):
        return message
    frames = traceback.extract_tb(error.__traceback__)
    where = f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{type(error).__name__}: {message}{where}"


# ---------------------------------------------------------------------------------------------------- serial
class _Task:
    __slots__ = ("function", "args", "num_returns", "tag", "value", "error")

    def __init__(self, function, args, num_returns, tag):
        self.function, self.args, self.num_returns, self.tag = function, args, num_returns, tag
        self.value: Any = None
        self.error: str | None = None


class Handle:
    """A serial task's future result (return ``index`` of it when it has several)."""

    __slots__ = ("task", "index")

    def __init__(self, task: _Task, index: int | None):
        self.task, self.index = task, index


class SerialExecutor:
    """Runs tasks in this process, one at a time, in submission order, as the driver reads :meth:`results`.

    Nothing runs at submit; a result is kept only while the driver or a later task still holds its handle, so a
    large sweep never has all its results in memory at once.
    """

    def __init__(self):
        self.queue: deque[_Task] = deque()

    def put(self, value):
        return value

    def submit(self, function: Callable, *args, tag: Any = None, num_returns: int = 1, num_gpus: float = 0.0):
        """Queue ``function(*args)``; its handle, or a tuple of ``num_returns`` handles. With a ``tag``, the
        result (the last return value when there are several) comes out of :meth:`results` as ``(tag, result)``.
        ``num_gpus`` is Ray's resource request; here every task runs in this process."""
        task = _Task(function, args, num_returns, tag)
        self.queue.append(task)
        return Handle(task, None) if num_returns == 1 else tuple(Handle(task, i) for i in range(num_returns))

    def results(self) -> Iterator[tuple[Any, Any]]:
        """Run the queued tasks in order; ``(tag, result)`` for each tagged one."""
        while self.queue:
            raise_pending()
            task = self.queue.popleft()
            self._run(task)
            if task.tag is not None:
                yield task.tag, {"error": task.error} if task.error is not None else \
                    (task.value if task.num_returns == 1 else task.value[-1])

    @staticmethod
    def _run(task: _Task) -> None:
        args = []
        for arg in task.args:
            if isinstance(arg, Handle):
                if arg.task.error is not None:  # as on Ray: a task fed by a failed one fails with the same reason
                    task.error = arg.task.error
                    break
                arg = arg.task.value if arg.index is None else arg.task.value[arg.index]
            args.append(arg)
        else:
            try:
                task.value = task.function(*args)
            except Exception as e:  # a crashed task: its result says why, the run goes on
                task.error = describe_error(e)
        task.function = task.args = None  # the inputs are no longer needed


# ------------------------------------------------------------------------------------------------------- ray
class RayExecutor:
    """Runs tasks as Ray tasks (one CPU each, OpenCV limited to ``runner.opencv_threads`` threads in them)."""

    def __init__(self, runner_cfg: Mapping, retries: int = 3):
        connect(runner_cfg)
        self.threads = runner_cfg.get("opencv_threads", default("runner.opencv_threads"))
        self.retries = retries
        self.remotes: dict[tuple, Any] = {}
        self.pending: dict[Any, Any] = {}  # ObjectRef of a tagged task -> tag

    def put(self, value):
        import ray

        return ray.put(value)

    def submit(self, function: Callable, *args, tag: Any = None, num_returns: int = 1, num_gpus: float = 0.0):
        """As :meth:`SerialExecutor.submit`; returns ObjectRefs (Ray resolves them when passed as arguments).
        ``num_gpus`` (fractional): the GPU share the task needs, so Ray runs it on a node with a GPU."""
        import ray

        key = (function, num_returns, float(num_gpus))
        if key not in self.remotes:
            self.remotes[key] = ray.remote(**self.resources(num_returns, num_gpus))(
                with_opencv_threads(function, self.threads))
        refs = self.remotes[key].remote(*args)
        if tag is not None:
            self.pending[refs[-1] if num_returns > 1 else refs] = tag
        return refs

    def resources(self, num_returns: int, num_gpus: float) -> dict:
        """``ray.remote``'s options for a task: one CPU, and ``num_gpus`` of a GPU where it asks for one."""
        options = {"num_cpus": 1, "num_returns": num_returns, "max_retries": self.retries}
        return {**options, "num_gpus": float(num_gpus)} if num_gpus else options

    def results(self, batch: int = 64) -> Iterator[tuple[Any, Any]]:
        """``(tag, result)`` as tagged tasks finish, collected ``batch`` at a time (one ``ray.wait`` per result
        would be quadratic in the number of tasks)."""
        import ray

        while self.pending:
            raise_pending()
            done, _ = ray.wait(list(self.pending), num_returns=min(batch, len(self.pending)), timeout=0.2)
            for ref in done:
                tag = self.pending.pop(ref)
                try:
                    result = ray.get(ref)
                except ray.exceptions.LocalRayletDiedError:
                    raise  # this process's own raylet: the cluster is lost, not the cell (core.errors.failure_cause)
                except ray.exceptions.RayError as e:  # the task raised, or its worker died
                    cause = getattr(e, "cause", None)
                    result = {"error": describe_error(cause) if isinstance(cause, Exception)
                              else f"Ray task failed: {(str(e).strip().splitlines() or [type(e).__name__])[0]}"}
                yield tag, result


def with_opencv_threads(function: Callable, threads: int | None) -> Callable:
    """``function`` run with OpenCV limited to ``threads`` threads: Ray runs one task per CPU, so OpenCV's own
    thread pool in every worker would only make the workers compete for the same cores."""

    @functools.wraps(function)
    def run(*args):
        if threads:
            import cv2

            cv2.setNumThreads(int(threads))
        return function(*args)

    return run


RAY_LOG_LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}


def ray_options(runner_cfg: Mapping) -> dict:
    """``ray.init`` options from ``runner``: the dashboard only when asked (``runner.dashboard=true``, which needs
    ``pip install 'ray[default]'``), Ray's own log lines at ``runner.ray_log_level`` (default ``error``: its
    warnings, such as the token-authentication notice of every local start, only when asked)."""
    level = runner_cfg.get("ray_log_level") or default("runner.ray_log_level")
    if level not in RAY_LOG_LEVELS:
        raise BadInput(f"runner.ray_log_level must be one of {', '.join(RAY_LOG_LEVELS)}, got {level!r}")
    dashboard = bool(runner_cfg.get("dashboard", default("runner.dashboard")))
    check_dashboard(runner_cfg)
    options = {"include_dashboard": dashboard, "logging_level": RAY_LOG_LEVELS[level], "log_to_driver": True}
    if dashboard:
        options["dashboard_host"] = "127.0.0.1"
    runtime_env = dict(runner_cfg.get("runtime_env") or {})
    if os.environ.get(plugins.ENV):  # the user's plugins may be factories in the workers too (any cluster)
        runtime_env["env_vars"] = {**(runtime_env.get("env_vars") or {}), plugins.ENV: os.environ[plugins.ENV]}
    if runtime_env:
        options["runtime_env"] = runtime_env
    return options


def _report_dashboard(context) -> None:
    url = getattr(context, "dashboard_url", "") or ""
    if url:
        url = url if "://" in url else f"http://{url}"
        log.info("Ray dashboard: %s", url)
        print(f"gtsweep: Ray dashboard at {url}", file=sys.stderr)


@contextlib.contextmanager
def _loopback_only():
    """Make ``ray.init`` start a node on 127.0.0.1. Ray 2.60 replaces ``_node_ip_address="127.0.0.1"`` by the
    machine's address (``services.resolve_ip_for_localhost``) unless its "no cluster" mode is on, the
    ``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0`` of macOS and Windows: then GCS, raylet, workers and agents bind to the
    loopback address only."""
    from ray._private import ray_constants

    key, before = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", ray_constants.ENABLE_RAY_CLUSTER
    saved = os.environ.get(key)
    os.environ[key], ray_constants.ENABLE_RAY_CLUSTER = "0", False
    try:
        yield
    finally:
        ray_constants.ENABLE_RAY_CLUSTER = before
        if saved is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = saved


#: The address this process joined a cluster with (``runner.address`` / ``$RAY_ADDRESS`` as given).
_joined: dict = {}


def _token_auth_if_available() -> None:
    """Ray's own rule for a cluster found on this machine: token authentication when ``RAY_AUTH_MODE`` is unset
    and a token exists (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``)."""
    try:
        from ray._private.authentication.authentication_token_setup import maybe_enable_token_auth_if_token_available
    except ImportError:  # a Ray without token authentication
        return
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)


def connect(runner_cfg: Mapping) -> None:
    """Start or join Ray once per process.

    ``address: local`` starts an embedded Ray that listens on 127.0.0.1 only (:func:`_loopback_only`; plain
    ``ray.init()`` would silently attach to a stale cluster recorded in /tmp/ray, and listen on every interface).
    ``auto`` joins the cluster this machine belongs to; ``host:port`` a remote head (probed first,
    :func:`check_address`), which since Ray 2.59 needs its token: export ``RAY_AUTH_MODE=token`` and
    ``RAY_AUTH_TOKEN`` (see README). The caller's SIGTERM handler is kept (``ray.init`` replaces it with one that
    exits at once).
    """
    import ray

    address = cluster_address(runner_cfg)
    if ray.is_initialized():
        current = ray.get_runtime_context().gcs_address
        if address in ("local", "auto") or address.split("://")[-1] == current or address == _joined.get("address"):
            return
        # Ray 2.60 hangs in its GCS client when a process that has run Ray joins another cluster after
        # ray.shutdown(): say so instead (the CLI runs one sweep per process, so only library use meets this).
        raise BadInput(f"this process already ran Ray (at {current}); joining the cluster at '{address}' after it "
                       f"hangs in Ray {ray.__version__}: run the sweep in a new process")
    check_address(runner_cfg)
    options = ray_options(runner_cfg)
    on_sigterm = signal.getsignal(signal.SIGTERM) if threading.current_thread() is threading.main_thread() else None
    try:
        if address == "local":
            num_cpus = runner_cfg.get("num_cpus")
            if num_cpus is not None and (not isinstance(num_cpus, int) or num_cpus < 1):
                raise BadInput(f"runner.num_cpus must be a positive integer or null, got {num_cpus!r}")
            with _loopback_only():
                _report_dashboard(ray.init(address="local", num_cpus=num_cpus, _node_ip_address="127.0.0.1",
                                           **options))
            record_cluster()
            return
        if this_machines_cluster(address):  # as `auto` joins it: with this machine's token, if it has one
            _token_auth_if_available()
        try:
            _report_dashboard(ray.init(address=address, **options))
            _joined["address"] = address  # Ray reports the head's own address, which may differ (127.0.0.1)
        except (ConnectionError, RuntimeError, ValueError) as e:
            hint = "" if address == "auto" else " (a remote head needs RAY_AUTH_MODE=token and RAY_AUTH_TOKEN)"
            raise BadInput(f"cannot join the Ray cluster at '{address}' ({address_source(runner_cfg)}): "
                           f"{str(e).splitlines()[0]}{hint}") from None
        record_cluster()
    finally:
        if on_sigterm is not None:
            signal.signal(signal.SIGTERM, on_sigterm)
