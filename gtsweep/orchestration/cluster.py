"""Which Ray cluster a run uses, whether it answers as one, and what it was.

The address is picked as ``ray.init()`` picks it (:func:`cluster_address`: ``runner.address``, else
``$RAY_ADDRESS``, else an embedded Ray); a ``host:port`` must answer within ``runner.connect_timeout_s`` as Ray's GCS
does (:func:`check_address`), before the MLflow parent run is created; once Ray is up, its address, nodes and CPUs
are printed and kept for ``run.json`` (:func:`record_cluster`, :func:`cluster_record`).
"""
from __future__ import annotations

import logging
import os
import socket
import sys
import time
from typing import Mapping

from gtsweep.core.errors import BadInput

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
    from gtsweep.orchestration.settings import SETTINGS

    address = cluster_address(runner_cfg)
    timeout = SETTINGS["runner.connect_timeout_s"].check("runner.connect_timeout_s",
                                                         runner_cfg.get("connect_timeout_s", 10))
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
        raise BadInput(f"cannot reach the Ray cluster at '{address}' ({address_source(runner_cfg)}) within {timeout:g} s "
                       f"(runner.connect_timeout_s): {reason}") from None
    if answer is None or answer[3] != HTTP2_SETTINGS:
        raise BadInput(f"'{address}' ({address_source(runner_cfg)}) accepts connections but is not a Ray head: it did not "
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
        except socket.timeout:
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
