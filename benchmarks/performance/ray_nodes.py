"""Trials per hour against Ray nodes, the launcher's per-job overhead, and the load a trial puts on the shared
stores (docs/scaling.md).

On one machine it starts what a cluster runs (tests/cluster.py): a throw-away PostgreSQL, an MLflow server on it,
a Ray head and, for the 2-node row, a second Ray node, each node pinned to one core of its own (taskset: a
worker renders and detects with every core it is given, so unpinned nodes on one machine share its cores and
two of them would measure nothing). Then:
1. the same search (tiny plan, 4-frame trials) with the local trial loop (no Ray, pinned to core 0 too), on 1
   Ray node with 1 worker
   and on 2 Ray nodes with 2 workers: steady trials per hour from the study's trial times, each worker's first
   trial (shader compilation, model loading) left out;
2. a dry-run sweep of 2 and of 10 jobs with the basic launcher and with `hydra/launcher=ray`: the marginal
   seconds a job costs, so the launcher's own overhead per job;
3. per trial: PostgreSQL commits (pg_stat_database, both databases) and the MLflow server's CPU seconds; and
   PostgreSQL's commit rate on this machine: what bounds a cluster's trials per hour.

Run: .venv/bin/python -m benchmarks.performance.ray_nodes [--trials 12] [--out benchmarks/results/ray_nodes.md]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import RESULTS, ROOT

sys.path.insert(0, str(ROOT / "tests"))  # the cluster's pieces (tests/cluster.py)
SMALL = ["plan=tiny", "case.motion.start=6", "case.motion.end=3", "case.motion.step=1", "camera.width=320",
         "camera.height=240", "detector.imgsz=320"]
PYTHON = str(ROOT / ".venv" / "bin" / "python")


def cpu_seconds(pids) -> float:
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in pids:
        try:
            fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12]) + int(fields[13]) + int(fields[14])) / tick
        except (OSError, IndexError):
            pass
    return total


def commits(pg) -> int:
    import psycopg

    with psycopg.connect(pg.url("postgres")) as con:
        return int(con.execute("SELECT sum(xact_commit) FROM pg_stat_database "
                               "WHERE datname IN ('mlflow', 'optuna')").fetchone()[0])


def commit_rate(pg, seconds: float = 3.0) -> float:
    """Small write transactions per second one connection gets (fsync off, as in the tests: an upper bound)."""
    import psycopg

    with psycopg.connect(pg.url("optuna"), autocommit=True) as con:
        con.execute("CREATE TABLE IF NOT EXISTS bench (k int primary key, v float)")
        con.execute("INSERT INTO bench VALUES (1, 0) ON CONFLICT DO NOTHING")
        n, end = 0, time.monotonic() + seconds
        while time.monotonic() < end:
            con.execute("UPDATE bench SET v = v + 1 WHERE k = 1")
            n += 1
    return n / seconds


def ask_seconds(url: str, n: int) -> float:
    """Seconds the study's lock is held for one trial once the study holds n trials: what search.loop does
    under the lock (fail stale trials, count, TPE's ask) on the PostgreSQL study, median of 5."""
    import statistics

    import optuna
    from optuna.distributions import FloatDistribution

    from garage_exp.search import storage as store

    space = {k: FloatDistribution(0.0, 1.0) for k in ("a", "b", "c")}
    storage = store.open_storage(url, heartbeat_interval=30, grace_period=120)
    study = optuna.create_study(storage=storage, study_name=f"ask-{n}", direction="maximize",
                                sampler=optuna.samplers.TPESampler(multivariate=True, seed=0))
    rng = __import__("random").Random(0)
    study.add_trials([optuna.trial.create_trial(params={k: rng.random() for k in space}, distributions=space,
                                                value=rng.random()) for _ in range(n)])
    times = []
    for _ in range(5):
        t = time.monotonic()
        with store.storage_lock(url):
            optuna.storages.fail_stale_trials(study)
            len(study.get_trials(deepcopy=False))
            trial = study.ask(fixed_distributions=space)
        times.append(time.monotonic() - t)
        study.tell(trial, rng.random())
    return statistics.median(times)


def run(args: list[str], cwd: Path, env: dict | None = None, core: int | None = None) -> float:
    t = time.monotonic()
    pin = ["taskset", "-c", str(core)] if core is not None else []
    r = subprocess.run([*pin, PYTHON, "-m", "garage_exp", *args], cwd=cwd, capture_output=True, text=True,
                       env={**os.environ, **(env or {})}, timeout=1800)
    if r.returncode != 0:
        raise SystemExit(f"failed: {' '.join(args)}\n{(r.stdout + r.stderr)[-3000:]}")
    return time.monotonic() - t


def steady_rate(url: str, study_name: str) -> tuple[float, int]:
    """Trials per hour once each worker is warm: the trials after each worker's first, over the span they took."""
    import optuna

    trials = sorted((t for t in optuna.load_study(study_name=study_name, storage=url).trials
                     if t.datetime_complete), key=lambda t: t.datetime_start)
    seen, warm = set(), []
    for t in trials:
        worker = t.user_attrs.get("worker")
        (warm.append(t) if worker in seen else seen.add(worker))
    span = (max(t.datetime_complete for t in warm) - min(t.datetime_start for t in warm)).total_seconds()
    return 3600.0 * len(warm) / span, len(warm)


def search(c, tmp: Path, tag: str, trials: int, ray: str | None, workers: int) -> tuple[float, float, int]:
    import optuna

    url = c["pg"].url("optuna")
    before = set(optuna.get_all_study_names(url))
    launcher = ["hydra/launcher=ray", f"hydra.launcher.address={ray}", f"hydra.launcher.workers={workers}"] \
        if ray else []
    wall = run(["-m", "hydra/sweeper=search", *launcher, f"search.storage={url}", f"search.trials={trials}",
                f"search.study=bench-{tag}", f"tracking.uri={c['uri']}", "light.intensity=interval(0.2,1.0)",
                "case.actors.target.distance=interval(3.0,8.0)", *SMALL, f"hydra.sweep.dir={tmp}/{tag}"], tmp,
               core=None if ray else 0)
    name = (set(optuna.get_all_study_names(url)) - before).pop()
    rate, n = steady_rate(url, name)
    return rate, wall, n


def sweep_overhead(c, tmp: Path, ray: str | None) -> float:
    """Seconds one more dry-run job adds: (wall of 10 jobs - wall of 2 jobs) / 8, on one core (the basic
    launcher pinned to core 0, Ray's one node pinned there)."""
    launcher = ["hydra/launcher=ray", f"hydra.launcher.address={ray}"] if ray else []
    walls = []
    for n in (2, 10):
        levels = ",".join(f"{0.1 + 0.08 * k:.2f}" for k in range(n))
        walls.append(run(["-m", *launcher, "dry_run=true", "plan=tiny", f"light.intensity={levels}",
                          f"tracking.uri={c['uri']}", f"hydra.sweep.dir={tmp}/dry{n}{'ray' if ray else ''}"], tmp,
                         core=None if ray else 0))
    return (walls[1] - walls[0]) / 8


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=16)
    ap.add_argument("--out", default=str(RESULTS / "ray_nodes.md"))
    a = ap.parse_args()
    from cluster import Postgres, mlflow_server, ray_node, ray_nodes_up

    from garage_exp.search.study import quiet_optuna

    quiet_optuna()

    tmp = Path(tempfile.mkdtemp(prefix="scaling"))
    ray_root = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))
    pg, procs, lines = Postgres(), [], []
    load_before = os.getloadavg()[0]
    try:
        pg.init("mlflow", "optuna")
        server, uri = mlflow_server(tmp, pg.url("mlflow"), tmp / "artifacts")
        procs.append(server)
        c = {"pg": pg, "uri": uri}
        os.environ["MLFLOW_TRACKING_URI"] = uri

        commits0, cpu0 = commits(pg), cpu_seconds(server.pids())
        local, local_wall, n_local = search(c, tmp, "local", a.trials, None, 1)
        per_trial_commits = (commits(pg) - commits0) / a.trials
        per_trial_server = (cpu_seconds(server.pids()) - cpu0) / a.trials

        head, address = ray_node(ray_root, "head", core=0)
        procs.append(head)
        ray_nodes_up(address, 1)
        one, one_wall, n_one = search(c, tmp, "ray1", a.trials, address, 1)
        basic_job, ray_job = sweep_overhead(c, tmp, None), sweep_overhead(c, tmp, address)  # one core each
        second, _ = ray_node(ray_root, "second", address, core=1)
        procs.append(second)
        ray_nodes_up(address, 2)
        two, two_wall, n_two = search(c, tmp, "ray2", a.trials, address, 2)

        rate = commit_rate(pg)
        asks = {n: ask_seconds(pg.url("optuna"), n) for n in (100, 1000, 3000)}

        lines += [
            f"search of {a.trials} trials (tiny plan, 4 frames of 320x240 a trial), PostgreSQL study, MLflow server on "
            "PostgreSQL; steady trials/hour (each worker's first trial left out)",
            "| setting | steady trials/hour | warm trials | wall (s) |", "|---|---:|---:|---:|",
            f"| local trial loop (no Ray) | {local:.0f} | {n_local} | {local_wall:.0f} |",
            f"| Ray, 1 node, 1 worker | {one:.0f} | {n_one} | {one_wall:.0f} |",
            f"| Ray, 2 nodes, 2 workers | {two:.0f} | {n_two} | {two_wall:.0f} |",
            "",
            f"2 nodes / 1 node: {two / one:.2f}x; Ray 1 node / local loop: {one / local:.2f}x",
            f"marginal seconds per dry-run job: basic launcher {basic_job:.2f} s, hydra/launcher=ray {ray_job:.2f} s "
            f"(overhead {ray_job - basic_job:+.2f} s a job)",
            f"per trial: {per_trial_commits:.0f} PostgreSQL commits (Optuna + MLflow), "
            f"{per_trial_server:.2f} s of MLflow server CPU",
            f"PostgreSQL small-commit rate, one connection: {rate:.0f}/s",
            f"bounds: PostgreSQL at one connection's rate {3600 * rate / per_trial_commits:.0f} trials/hour; "
            f"one MLflow server worker {3600 / max(per_trial_server, 1e-9):.0f} trials/hour",
            "seconds the study's lock is held per trial (fail stale, count, TPE ask) at n trials: " +
            ", ".join(f"n={n}: {t:.3f} s (bound {3600 / t:.0f} trials/hour)" for n, t in asks.items()),
            f"machine: {os.cpu_count()} cores; load average {load_before:.1f} before, {os.getloadavg()[0]:.1f} after; "
            f"date {time.strftime('%Y-%m-%d')}",
        ]
    finally:
        for p in procs:
            p.kill()
        pg.kill()
        shutil.rmtree(ray_root, ignore_errors=True)
    text = "\n".join(lines)
    print(text)
    if lines:
        Path(a.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
