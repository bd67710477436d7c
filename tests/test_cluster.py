"""Which Ray cluster a run uses (issue 27: ``RAY_ADDRESS`` as ``ray.init()`` reads it; the cluster printed and in
``run.json``) and a bounded wait for it (issue 28, item 5: a port that accepts TCP but is not Ray is refused within
``runner.connect_timeout_s``, SIGTERM honoured meanwhile, no MLflow parent run created)."""
from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

from gtsweep.core.errors import BadInput
from gtsweep.orchestration.cluster import check_address, cluster_address
from sweep_helpers import cli_env, session_ends, session_processes, tiny_overrides

# Real Ray heads and test clusters, one at a time on one test worker (make test runs pytest-xdist with --dist
# loadgroup): each takes the 2 cores' worth of processes a sweep does
pytestmark = pytest.mark.xdist_group("real_ray_heads")


class SilentServer:
    """A TCP port that accepts connections and never says a word (or, ``reply``, answers like a web server)."""

    def __init__(self, reply: bytes | None = None):
        self.socket = socket.socket()
        self.socket.bind(("127.0.0.1", 0))
        self.socket.listen(8)
        self.port = self.socket.getsockname()[1]
        self.accepted = threading.Event()
        self.reply, self.held = reply, []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                connection, _ = self.socket.accept()
            except OSError:
                return
            self.accepted.set()
            if self.reply is not None:
                connection.sendall(self.reply)
                connection.close()
            else:
                self.held.append(connection)

    def close(self):
        self.socket.close()
        for connection in self.held:
            connection.close()


@pytest.fixture
def silent():
    server = SilentServer()
    yield server
    server.close()


def test_a_port_that_accepts_but_is_not_ray_is_refused_within_the_timeout(silent):
    start = time.perf_counter()
    with pytest.raises(BadInput, match=r"accepts connections but is not a Ray head.* within 1 s"):
        check_address({"address": f"127.0.0.1:{silent.port}", "connect_timeout_s": 1})
    assert time.perf_counter() - start < 2.5
    web = SilentServer(reply=b"HTTP/1.1 400 Bad Request\r\n\r\n")
    try:
        with pytest.raises(BadInput, match="is not a Ray head"):
            check_address({"address": f"127.0.0.1:{web.port}", "connect_timeout_s": 1})
    finally:
        web.close()


def test_ray_address_is_read_as_ray_init_reads_it(monkeypatch, silent):
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    assert cluster_address({"address": None}) == "local"
    monkeypatch.setenv("RAY_ADDRESS", "auto")
    assert cluster_address({"address": None}) == "auto"
    assert cluster_address({"address": "local"}) == "local"  # the setting, when given, wins
    monkeypatch.setenv("RAY_ADDRESS", f"127.0.0.1:{silent.port}")
    with pytest.raises(BadInput, match=r"\(RAY_ADDRESS\) accepts connections but is not a Ray head"):
        check_address({"address": None, "connect_timeout_s": 1})


def _cli(tmp_path: Path, *args: str, env: dict | None = None) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "gtsweep", *tiny_overrides(tmp_path, "report.plots=false"), *args],
                            cwd=tmp_path, env={**cli_env(), **(env or {})}, text=True, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)


def _no_parent_run(tmp_path: Path) -> None:
    from mlflow.tracking import MlflowClient

    if (tmp_path / "mlflow.db").exists():
        client = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}")
        assert client.search_runs([e.experiment_id for e in client.search_experiments()]) == []


@pytest.mark.slow
def test_cli_refuses_a_port_that_is_not_ray_in_one_line_before_the_parent_run(tmp_path, silent):
    start = time.perf_counter()
    run = _cli(tmp_path, "runner.backend=ray", f"runner.address=127.0.0.1:{silent.port}",
               "runner.connect_timeout_s=2")
    out, err = run.communicate(timeout=120)
    assert run.returncode == 2 and len(err.strip().splitlines()) == 1 and "is not a Ray head" in err, err
    assert time.perf_counter() - start < 40  # Python, Hydra and the imports, then 2 s
    _no_parent_run(tmp_path)
    run = _cli(tmp_path, "runner.backend=ray", "runner.connect_timeout_s=2",  # the source is named, at any wait
               env={"RAY_ADDRESS": f"127.0.0.1:{silent.port}"})
    out, err = run.communicate(timeout=120)
    assert run.returncode == 2 and "(RAY_ADDRESS) accepts connections but is not a Ray head" in err, err


@pytest.mark.slow
def test_sigterm_while_waiting_for_a_cluster_stops_at_once(tmp_path, silent):
    run = _cli(tmp_path, "runner.backend=ray", f"runner.address=127.0.0.1:{silent.port}",
               "runner.connect_timeout_s=60")
    assert silent.accepted.wait(timeout=90), "the run never probed the address"
    start = time.perf_counter()
    run.send_signal(signal.SIGTERM)
    out, err = run.communicate(timeout=30)
    assert time.perf_counter() - start < 10
    assert run.returncode == 143 and len(err.strip().splitlines()) == 1 and "interrupted by SIGTERM" in err, err
    _no_parent_run(tmp_path)


_JOIN_BY_RAY_ADDRESS = """
import os, sys, json
from pathlib import Path
from ray.cluster_utils import Cluster
from sweep_helpers import compose_config, tiny_overrides
from gtsweep.experiments.kinds import run_sweep

tmp = Path(sys.argv[1])
cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
try:
    os.environ["RAY_ADDRESS"] = cluster.address
    cfg = compose_config(tiny_overrides(tmp, "runner.backend=ray", "mlflow.enabled=false", "detector=[orb]",
                                        "descriptor=[orb]", "transform=[incremental]"))
    run_sweep(cfg, tmp / "joined")
    print(json.dumps({"expected": cluster.address, "record": json.loads((tmp / "joined/run.json").read_text())}))
finally:
    import ray
    ray.shutdown()
    cluster.shutdown()
"""


@pytest.mark.slow
def test_ray_address_joins_the_running_head_and_the_run_records_the_cluster(tmp_path):
    env = {**cli_env(), "PYTHONPATH": os.pathsep.join([cli_env()["PYTHONPATH"], str(Path(__file__).parent)])}
    done = subprocess.run([sys.executable, "-c", _JOIN_BY_RAY_ADDRESS, str(tmp_path)], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    cluster = result["record"]["cluster"]
    assert cluster == {"backend": "ray", "address": result["expected"], "nodes": 1, "cpus": 1}
    assert f"Ray cluster at {result['expected']}: 1 node(s), 1 CPUs" in done.stderr


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _recorded_cluster(ray_tmpdir: str) -> str | None:
    """The cluster ``ray start`` recorded under ``RAY_TMPDIR`` (in its ``ray`` folder, as Ray reads it)."""
    from ray._private.utils import read_ray_address

    return read_ray_address(str(Path(ray_tmpdir) / "ray"))


@pytest.fixture(scope="module")
def ray_home(tmp_path_factory) -> Path:
    """A home with a Ray token, as every machine that has started Ray locally has one (``~/.ray/auth_token``):
    the head and the runs that join it read it there, whether or not this machine's own home has one yet."""
    import secrets

    home = tmp_path_factory.mktemp("ray_home")
    (home / ".ray").mkdir()
    (home / ".ray" / "auth_token").write_text(secrets.token_hex(32))
    return home


@pytest.fixture
def ray_head(tmp_path_factory, ray_home):
    """A real head as a user starts it (``ray start --head --node-ip-address=127.0.0.1``, 1 CPU, this Python so
    that its workers import this checkout), in a session of its own: stopped by its process group afterwards
    (never ``ray stop``, which would stop every Ray on the machine). Yields its port and the environment a user
    of this machine has (``HOME`` with the token; ``RAY_TMPDIR``, where ``ray start`` records its cluster and
    ``auto`` and gtsweep look for it). That Ray directory is the head's own: the machine's
    /tmp/ray/ray_current_cluster is one file that every Ray test cluster on the machine rewrites and deletes
    (``cluster_utils.Cluster`` does both), and with ``RAY_AUTH_MODE`` unset a run sends the token only when that
    record names the head it joins. Short, under /tmp: Ray's sockets live in it."""
    tmp_path = tmp_path_factory.mktemp("ray_head")
    user = {"HOME": str(ray_home), "RAY_TMPDIR": tempfile.mkdtemp(prefix="rt", dir="/tmp")}
    port = _free_port()
    head = subprocess.Popen(
        [sys.executable, "-c", "from ray.scripts.scripts import main; main()", "start", "--head", "--block",
         "--node-ip-address=127.0.0.1", f"--port={port}", "--num-cpus=1", "--include-dashboard=false",
         "--disable-usage-stats"], env={**cli_env(), **user}, cwd=tmp_path, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (_recorded_cluster(user["RAY_TMPDIR"]) or "").endswith(f":{port}"):
            assert head.poll() is None, head.stderr.read()[-2000:]  # ended: its stderr is whole
            assert time.monotonic() < deadline, f"ray start recorded no cluster under {user['RAY_TMPDIR']} in 120 s"
            time.sleep(0.5)
        yield port, user
    finally:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(head.pid, sig)
            except ProcessLookupError:
                break
            _gone_within(head, 3)
        head.wait(timeout=30)
        assert session_ends(head.pid, timeout=10) == []
        shutil.rmtree(user["RAY_TMPDIR"], ignore_errors=True)


def _gone_within(head: subprocess.Popen, seconds: float) -> None:
    """Wait until every process of ``head``'s session has ended (the head itself reaped), at most ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and (head.poll() is None or session_processes(head.pid)):
        time.sleep(0.1)


@pytest.mark.slow
@pytest.mark.parametrize("auth_mode", [None, "token"])
def test_ray_address_of_a_local_head_runs_the_sweep_there(tmp_path, ray_head, auth_mode, monkeypatch):
    """As ``ray.init(address="auto")`` joins this machine's head with its token; with ``RAY_AUTH_MODE=token`` as
    Ray asks of an explicit address. The head reports its own address (not 127.0.0.1): joining does not refuse."""
    port, user = ray_head
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    env = {**user, "RAY_ADDRESS": f"127.0.0.1:{port}", **({"RAY_AUTH_MODE": auth_mode} if auth_mode else {})}
    run = _cli(tmp_path, "runner.backend=ray", "mlflow.enabled=false", "detector=[orb]", "descriptor=[orb]",
               "transform=[incremental]", "hydra.run.dir=out", env=env)
    out, err = run.communicate(timeout=300)
    assert run.returncode == 0, err[-2000:]
    cluster = json.loads((tmp_path / "out" / "run.json").read_text())["cluster"]
    assert cluster["address"].endswith(f":{port}") and (cluster["nodes"], cluster["cpus"]) == (1, 1)
    assert f"Ray cluster at {cluster['address']}: 1 node(s), 1 CPUs" in err
