"""Which Ray cluster a run uses, whether it answers as one, and what it was.

The address is picked as ``ray.init()`` picks it (:func:`cluster_address`: ``runner.address``, else
``$RAY_ADDRESS``, else an embedded Ray); a ``host:port`` must answer within ``runner.connect_timeout_s`` as Ray's GCS
does (:func:`check_address`), before the MLflow parent run is created; once Ray is up, its address, nodes and CPUs
are printed and kept for ``run.json`` (:func:`record_cluster`, :func:`cluster_record`). When a run stops,
:func:`stop_workers` ends Ray and every Ray process this command started (:func:`leftover_ray_processes`).
"""
from __future__ import annotations

import atexit
import contextlib
import logging
import os
import re
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Mapping, NoReturn

from gtsweep.core.errors import BadInput
from gtsweep.orchestration.settings import default

log = logging.getLogger(__name__)


def cluster_address(runner_cfg: Mapping) -> str:
    """The cluster to use, as ``ray.init()`` picks it: ``runner.address`` when given, else ``$RAY_ADDRESS``, else
    ``local`` (an embedded Ray)."""
    return str(runner_cfg.get("address") or os.environ.get("RAY_ADDRESS") or "local")


def this_machines_cluster(address: str) -> bool:
    """Whether ``host:port`` names the cluster this machine runs (the one ``ray start`` recorded, which ``auto``
    finds): the same port, on a loopback address or the recorded host. Ray joins that one as ``auto`` does, with
    its token when it has one (an explicit address of another machine needs ``RAY_AUTH_MODE=token``)."""
    try:
        from ray._private.utils import read_ray_address

        recorded = read_ray_address()
    except (ImportError, OSError):
        return False
    if not recorded or address in ("local", "auto"):
        return False
    host, _, port = address.split("://")[-1].rpartition(":")
    recorded_host, _, recorded_port = recorded.rpartition(":")
    return port == recorded_port and (host in (recorded_host, "localhost") or host.startswith("127."))


def address_source(runner_cfg: Mapping) -> str:
    return "runner.address" if runner_cfg.get("address") else "RAY_ADDRESS"


#: An HTTP/2 client's first bytes: the connection preface and an empty SETTINGS frame. Ray's GCS (gRPC) answers
#: with a SETTINGS frame of its own at once; a port that is not a Ray head does not.
HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])
HTTP2_SETTINGS = 4


def check_address(runner_cfg: Mapping) -> None:
    """A ``host:port`` cluster address (``runner.address`` or ``$RAY_ADDRESS``) must answer as a Ray head does
    within ``runner.connect_timeout_s``: accept a TCP connection and answer gRPC's HTTP/2 greeting. Ray itself
    retries "Failed to connect to GCS" for minutes, and hangs on a port that accepts but is not Ray. ``local`` and
    ``auto`` need no probe (``auto`` is resolved and refused at once by Ray when no cluster runs)."""
    address = cluster_address(runner_cfg)
    timeout = runner_cfg.get("connect_timeout_s", default("runner.connect_timeout_s"))  # range: check_settings
    if address in ("local", "auto"):
        return
    host, _, port = address.split("://")[-1].rpartition(":")
    if not host or not port.isdigit():
        raise BadInput(f"{address_source(runner_cfg)} must be local, auto or host:port, got {address!r}")
    deadline = time.monotonic() + timeout
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout) as connection:
            answer = _greet(connection, deadline)
    except OSError as e:
        reason = "timed out" if isinstance(e, socket.timeout) else e.strerror or str(e)
        raise BadInput(f"cannot reach the Ray cluster at '{address}' ({address_source(runner_cfg)}) within "
                       f"{timeout:g} s "
                       f"(runner.connect_timeout_s): {reason}") from None
    if answer is None or answer[3] != HTTP2_SETTINGS:
        raise BadInput(f"'{address}' ({address_source(runner_cfg)}) accepts connections but is not a Ray head: "
                       f"it did not "
                       f"answer as Ray's GCS (gRPC) does within {timeout:g} s (runner.connect_timeout_s)")


def _greet(connection: socket.socket, deadline: float) -> bytes | None:
    """Send the HTTP/2 greeting; the 9-byte header of the first frame that comes back (None: the peer closed)."""
    connection.settimeout(max(deadline - time.monotonic(), 0.01))
    connection.sendall(HTTP2_PREFACE)
    head = b""
    while len(head) < 9:
        connection.settimeout(max(deadline - time.monotonic(), 0.01))
        try:
            chunk = connection.recv(9 - len(head))
        except TimeoutError:
            return None
        if not chunk:
            return None
        head += chunk
    return head


#: The cluster this process ran its Ray tasks on (:func:`connect`): address, nodes, CPUs.
_cluster: dict = {}


def cluster_record() -> dict:
    """For ``run.json`` and MLflow: where this process ran its tasks — ``{"backend": "serial"}``, or Ray's cluster
    address, its alive nodes and CPUs; empty when no task ran (a resume with nothing left to do)."""
    return dict(_cluster)


def record_serial() -> None:
    _cluster.clear()
    _cluster["backend"] = "serial"


def record_cluster() -> None:
    """Remember and print the cluster Ray runs on (one line on stderr, also in the job's log)."""
    import ray

    nodes = [n for n in ray.nodes() if n.get("Alive")]
    _cluster.clear()
    _cluster.update(backend="ray", address=ray.get_runtime_context().gcs_address, nodes=len(nodes),
                    cpus=int(sum(n.get("Resources", {}).get("CPU", 0) for n in nodes)))
    line = f"Ray cluster at {_cluster['address']}: {_cluster['nodes']} node(s), {_cluster['cpus']} CPUs"
    log.info(line)
    print(f"gtsweep: {line}", file=sys.stderr)


STOP_ROUNDS, STOP_PAUSE_S = 10, 0.2
_stopped = {"ray": False}  # whether stop_workers ended this process's Ray


def stop_workers() -> None:
    """Shut down Ray if this process started or joined it, then end Ray's processes of this command that outlived
    it (a Ctrl-C that reaches the whole process group while Ray starts can kill the raylet before its agents).
    A raylet can still be starting an agent while it is ended, so the search repeats until it finds nothing."""
    ray = sys.modules.get("ray")
    if ray is None:
        return
    if ray.is_initialized():
        with contextlib.suppress(Exception):
            ray.shutdown()
    _stopped["ray"] = True
    end_ray_processes(os.path.dirname(getattr(ray, "__file__", None) or "") or None)


def end_ray_processes(ray_dir: str | None, owner: int | None = None) -> None:
    """End the Ray processes of ``owner``'s command (:func:`leftover_ray_processes`; default: this process), until
    none is found (a raylet can still be starting an agent while it is ended)."""
    for _ in range(STOP_ROUNDS):
        leftovers = leftover_ray_processes(ray_dir=ray_dir, owner=owner)
        if not leftovers:
            return
        for pid in leftovers:
            with contextlib.suppress(OSError):
                os.kill(pid, signal.SIGKILL)
        time.sleep(STOP_PAUSE_S)


def leave(code: int | str | None) -> NoReturn:
    """End the process with a :class:`SystemExit`'s ``code``. After :func:`stop_workers` ended Ray, the process
    skips C's exit handlers: once its raylet and GCS are gone, Ray's core-worker exit handler
    (``CoreWorkerProcess::HandleAtExit``, Ray 2.60) waits for the dead GCS and then crashes the process (SIGSEGV:
    exit status -11 instead of 130). Python's own exit work (atexit functions, logging, the streams) is done first."""
    if not _stopped["ray"]:
        sys.exit(code)
    if isinstance(code, str):  # sys.exit("message"): Python prints it
        print(code, file=sys.stderr)
    atexit._run_exitfuncs()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code if isinstance(code, int) else (0 if code is None else 1))


#: Ray names a node's session after the process that starts it: ``session_<date>_<time>_<microseconds>_<pid>``
#: (``ray._private.node.Node``); every process of the node names that folder in its command line or its open files.
SESSION = re.compile(rb"session_\d{4}-\d\d-\d\d_\d\d-\d\d-\d\d_\d+_(\d+)(?![\d])")


def leftover_ray_processes(proc: Path = Path("/proc"), ray_dir: str | None = None,
                           owner: int | None = None) -> list[int]:
    """Ray's processes that this command started, and nothing else's (Linux; elsewhere none): a Ray program
    (``ray::...``, raylet, GCS, or a script of Ray's package in ``ray_dir``) that descends from ``owner`` (default:
    this process; the watchdog names its dead sweep), or that names the Ray session ``owner`` started (by its pid)
    and began after this process. An orphaned agent is found whatever its process group; a cluster the user
    started with ``ray start`` (another session) or another command's Ray is never matched."""
    me = os.getpid()
    owner = owner or me
    table = _processes(proc, ray_dir)
    if me not in table:
        return []
    born = table[me]["start"]

    def descends(pid: int) -> bool:
        seen = set()
        while pid not in (0, 1) and pid not in seen:
            seen.add(pid)
            pid = table.get(pid, {}).get("ppid", 0)
            if pid == owner:
                return True
        return False

    def names_my_session(pid: int) -> bool:
        texts = [table[pid]["cmdline"], *_open_files(proc / str(pid))]
        return table[pid]["start"] >= born and any(
            int(m.group(1)) == owner for text in texts for m in SESSION.finditer(text))

    return sorted(pid for pid, info in table.items()
                  if pid not in (me, owner) and info["ray"] and (descends(pid) or names_my_session(pid)))


def _processes(proc: Path, ray_dir: str | None) -> dict[int, dict]:
    """pid -> parent, start time (clock ticks after boot), command line and whether it is a Ray program."""
    marker = os.fsencode(ray_dir.rstrip("/") + "/") if ray_dir else None
    table = {}
    for entry in proc.glob("[0-9]*"):
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            argv = (entry / "cmdline").read_bytes().split(b"\0")
        except (OSError, ValueError, IndexError):
            continue
        program = argv[0]
        ray = program.startswith(b"ray::") or os.path.basename(program) in (b"raylet", b"gcs_server") or (
            marker is not None and any(arg.startswith(marker) for arg in argv[:3]))
        try:
            table[int(entry.name)] = {"ppid": int(fields[1]), "start": int(fields[19]), "ray": ray,
                                      "cmdline": b" ".join(argv)}
        except (ValueError, IndexError):
            continue
    return table


def _open_files(process: Path) -> list[bytes]:
    """Where ``process``'s file descriptors point (its logs in the Ray session folder); none if not readable."""
    targets = []
    with contextlib.suppress(OSError):
        for fd in (process / "fd").iterdir():
            with contextlib.suppress(OSError):
                targets.append(os.fsencode(os.readlink(fd)))
    return targets
