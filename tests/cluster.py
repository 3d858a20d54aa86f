"""A throw-away cluster on localhost for the cluster tests: PostgreSQL, an MLflow server on it, Ray nodes.

Every process is started in its own session and stopped by its process group (never `ray stop` or
`pg_ctl stop` of something we did not start), on every path: `Cluster.close` kills what is left.
"""

from __future__ import annotations

import glob
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

from conftest import PYTHON
from mlflow_server import free_port

BIN = Path(PYTHON).parent


def pg_bin(name: str) -> str | None:
    found = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return found[-1] if found else shutil.which(name)


def cluster_problem() -> str | None:
    """Why a local cluster cannot start here (None when it can)."""
    if pg_bin("initdb") is None or pg_bin("pg_ctl") is None:
        return "PostgreSQL's initdb/pg_ctl are not installed (make setup installs postgresql)"
    for module in ("ray", "psycopg"):
        try:
            __import__(module)
        except ImportError:
            return f"python package {module} missing (make setup installs the test extra)"
    if os.geteuid() == 0 and shutil.which("runuser") is None:
        return "running as root without runuser: PostgreSQL refuses to run as root"
    return None


def _as_postgres(cmd: list[str]) -> list[str]:
    """initdb and postgres refuse to run as root: as root, run them as the postgres user."""
    return ["runuser", "-u", "postgres", "--", *cmd] if os.geteuid() == 0 else cmd


def wait_for(check, what: str, timeout: float = 120.0, proc: subprocess.Popen | None = None, log: Path | None = None,
             every: float = 0.25):
    """check()'s first true value, asked every `every` seconds until `timeout`; AssertionError (with the log's
    tail) when it runs out or `proc` exits."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            value = check()
            if value:
                return value
        except Exception:  # noqa: BLE001 - not up yet
            pass
        if proc is not None and proc.poll() is not None:
            raise AssertionError(f"{what} exited {proc.returncode}: " + (log.read_text()[-3000:] if log else ""))
        if time.monotonic() > deadline:
            raise AssertionError(f"{what} did not come up in {timeout:.0f} s: " + (log.read_text()[-3000:] if log else ""))
        time.sleep(every)


class Postgres:
    """A PostgreSQL server on 127.0.0.1 with its data in a temp dir (trust auth, user postgres)."""

    def __init__(self):
        import tempfile

        # its own dir under /tmp: pytest's tmp dirs are private to this user (0700), which the postgres user
        # (as root we run the server as postgres) cannot enter
        self.root = Path(tempfile.mkdtemp(prefix="pg", dir="/tmp"))
        os.chmod(self.root, 0o755)
        self.data, self.sockets, self.log = self.root / "data", self.root / "sock", self.root / "postgres.log"
        self.port = free_port()
        self.pid: int | None = None

    def url(self, db: str) -> str:
        return f"postgresql://postgres@127.0.0.1:{self.port}/{db}"

    def init(self, *dbs: str) -> None:
        for d in (self.data, self.sockets):
            d.mkdir(parents=True)
        if os.geteuid() == 0:
            for p in (self.root, self.data, self.sockets):
                shutil.chown(p, "postgres", "postgres")
            self.log.touch()
            shutil.chown(self.log, "postgres", "postgres")
        subprocess.run(_as_postgres([pg_bin("initdb"), "-D", str(self.data), "-U", "postgres", "--auth=trust",
                                     "--no-sync", "-E", "UTF8"]), check=True, capture_output=True, timeout=120)
        self.start()
        import psycopg

        con = psycopg.connect(self.url("postgres"), autocommit=True)
        for db in dbs:
            con.cursor().execute(f'CREATE DATABASE "{db}"')
        con.close()

    def start(self) -> None:
        options = f"-p {self.port} -k {self.sockets} -c listen_addresses=127.0.0.1 -c fsync=off"
        for attempt in range(3):  # a loaded machine: pg_ctl's own wait (60 s) can run out once
            r = subprocess.run(_as_postgres([pg_bin("pg_ctl"), "-D", str(self.data), "-o", options, "-l",
                                             str(self.log), "-t", "120", "-w", "start"]),
                               capture_output=True, text=True, timeout=180)
            if r.returncode == 0 or "another server might be running" in r.stderr:
                break
        else:
            raise AssertionError(f"pg_ctl start: {r.stdout} {r.stderr} {self.log_tail()}")
        self.pid = int((self.data / "postmaster.pid").read_text().split()[0])

    def log_tail(self) -> str:
        try:
            return "\n--- postgres.log ---\n" + self.log.read_text()[-2000:]
        except OSError:
            return ""

    def stop(self) -> None:
        """A fast shutdown (open connections are cut), as an operator's restart or a failover does."""
        if self.pid is None:
            return
        subprocess.run(_as_postgres([pg_bin("pg_ctl"), "-D", str(self.data), "-m", "fast", "-w", "stop"]),
                       capture_output=True, timeout=60)
        self.pid = None

    def kill(self) -> None:
        if self.pid is None and (self.data / "postmaster.pid").exists():  # started, its start not seen through
            self.pid = int((self.data / "postmaster.pid").read_text().split()[0])
        if self.pid is not None:
            try:
                os.kill(self.pid, signal.SIGQUIT)  # the postmaster's immediate shutdown: its children go too
            except ProcessLookupError:
                pass
            self.pid = None
        shutil.rmtree(self.root, ignore_errors=True)


class Process:
    """A command in its own session, stopped by its process group."""

    def __init__(self, cmd: list[str], log: Path, env: dict | None = None, cwd: Path | None = None):
        self.log = log
        out = open(log, "ab")
        self.proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=cwd,
                                     start_new_session=True)
        out.close()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def pids(self) -> set[int]:
        """Every process of the session (Ray's raylet and its workers included)."""
        out = set()
        for entry in os.listdir("/proc"):
            if entry.isdigit():
                try:
                    if os.getsid(int(entry)) == self.proc.pid:
                        out.add(int(entry))
                except OSError:
                    pass
        return out

    def kill(self) -> None:
        for sig in (signal.SIGCONT, signal.SIGKILL):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                pass
        for pid in self.pids():  # a child that left the group (none expected)
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            pass


def mlflow_server(root: Path, backend: str, artifacts: Path) -> tuple[Process, str]:
    """`mlflow server` with its runs in `backend` (PostgreSQL) and the artifacts on a directory every node
    shares (clients write there themselves: --no-serve-artifacts)."""
    import urllib.request

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "MLFLOW_TRACKING_URI")}
    log = root / "mlflow_server.log"
    for attempt in range(3):
        # a free port can be taken before the server binds it (Ray's workers open ports all the time, and the
        # server takes seconds to start): then the server exits saying so, and another port is tried
        port, seen = free_port(), log.stat().st_size if log.exists() else 0
        proc = Process([str(BIN / "mlflow"), "server", "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
                        "--backend-store-uri", backend, "--no-serve-artifacts", "--default-artifact-root",
                        str(artifacts)], log, env=env, cwd=root)
        uri = f"http://127.0.0.1:{port}"

        def up():
            with urllib.request.urlopen(f"{uri}/health", timeout=2) as r:
                return r.status == 200

        try:
            wait_for(up, "mlflow server", 180, proc.proc, proc.log)
            return proc, uri
        except AssertionError:
            taken = proc.proc.poll() is not None and "address already in use" in log.read_text()[seen:]
            if not taken or attempt == 2:
                raise
    raise AssertionError("unreachable")


# Ray 2.60 turns token authentication on for a head started where a token file exists (~/.ray/auth_token, which
# a local `ray.init()` writes), while its clients default to no token: the throw-away cluster runs without it.
def ray_env() -> dict:
    return {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled"}


def ray_node(root: Path, name: str, head: str | None = None, core: int | None = None) -> tuple[Process, str]:
    """A Ray node with one CPU, on 127.0.0.1: the head (head=None) or a node joining it. `core`: pin the node
    and every worker it starts to that core (taskset), so that a node is one core as a benchmark's node is."""
    env = ray_env()
    common = ["--block", "--num-cpus", "1", "--node-ip-address", "127.0.0.1", "--disable-usage-stats"]
    if head is None:
        port = free_port()
        cmd = [str(BIN / "ray"), "start", "--head", "--port", str(port), "--include-dashboard=false",
               "--temp-dir", str(root), *common]
        address = f"127.0.0.1:{port}"
    else:
        cmd, address = [str(BIN / "ray"), "start", "--address", head, *common], head
    if core is not None:
        cmd = ["taskset", "-c", str(core), *cmd]
    proc = Process(cmd, root.parent / f"ray_{name}.log", env=env)
    return proc, address


def ray_nodes_up(address: str, count: int, timeout: float = 120.0) -> None:
    """Wait until the cluster's GCS holds `count` live nodes. Asked here, through Ray's own GCS client (what
    `ray status` and Serve ask), not by polling `ray status`: each of its runs is an interpreter importing Ray
    (seconds of CPU, on the cores the nodes are starting on), and it shows the autoscaler's view, seconds late."""
    from ray._raylet import GcsClient
    from ray.core.generated.gcs_pb2 import GcsNodeInfo

    def up():
        nodes = GcsClient(address=address).get_all_node_info(timeout=5)
        return sum(node.state == GcsNodeInfo.ALIVE for node in nodes.values()) >= count

    wait_for(up, f"{count} Ray node(s)", timeout)
