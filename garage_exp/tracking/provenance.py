"""What identifies a job and a sweep, and what a run records about where it came from: the config's hash and
params, the plan file's digest, the git commit, run names and sweep keys. Plain data: no MLflow."""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path
from typing import Any

from garage_exp.core.plain import plain

from garage_exp.core.state import STATE
from garage_exp.core.paths import PROJECT_ROOT

NAME_MAX = 250  # MLflow's runs.name column: sqlite ignores the length, PostgreSQL refuses a longer name


@STATE.memo("process", maxsize=1)
def git_commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT, capture_output=True, text=True,
                             timeout=5).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=PROJECT_ROOT,
                               capture_output=True, text=True, timeout=5).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return (sha or "unknown") + ("-dirty" if dirty else "")


def flatten(node: Any, prefix: str = "") -> dict[str, str]:
    """Flatten a nested config into dotted keys with string values (MLflow params)."""
    out: dict[str, str] = {}
    if isinstance(node, dict):
        for key, value in node.items():
            out.update(flatten(value, f"{prefix}{key}."))
    elif isinstance(node, list) and any(isinstance(v, (dict, list)) for v in node):
        for k, value in enumerate(node):
            out.update(flatten(value, f"{prefix}{k}."))
    else:
        out[prefix[:-1]] = str(node)[:6000]
    return out


def config_params(cfg) -> dict[str, str]:
    container = plain(cfg)
    container.pop("hydra", None)
    _drop_unset_plan_keys(container)
    return flatten(container)


def _drop_unset_plan_keys(container: dict) -> None:
    """plan.seed and plan.generator (plan=generated) unset: not logged, not hashed, as before they existed."""
    if isinstance(container.get("plan"), dict):
        for key in ("seed", "generator"):
            if key in container["plan"] and container["plan"][key] is None:
                container["plan"].pop(key)


def file_digest(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def config_hash(cfg, plan_digest: str = "") -> str:
    """Identity of a job: the composed config without the keys that do not change its result, plus the
    content of its plan file (an edited plan is a different job, though its name is the same)."""
    container = plain(cfg)
    for key in ("hydra", "resume", "tracking"):
        container.pop(key, None)
    if isinstance(container.get("detector"), dict):  # where `models:/` entries are looked up: the tracking store
        container["detector"].pop("registry", None)
        if not container["detector"].get("class_names"):  # added later: an empty one keeps older jobs' identity
            container["detector"].pop("class_names", None)
    _drop_unset_plan_keys(container)  # added for plan=generated: unset, they keep older jobs' identity
    if isinstance(container.get("renderer"), dict) and container["renderer"].get("backend") == "sapien":
        container["renderer"].pop("backend")  # added with the backends' registry: the default keeps older jobs'
    if plan_digest:
        container["plan_sha256"] = plan_digest
    return hashlib.sha256(json.dumps(container, sort_keys=True, default=str).encode()).hexdigest()[:16]


def describes_run(override: str) -> bool:
    """Whether an override changes what runs: `resume` and `tracking.*` (where it is logged) do not."""
    key = override.split("=", 1)[0].lstrip("+~")
    return key != "resume" and not key.startswith("tracking.") and key != "tracking"


def fit_name(name: str) -> str:
    """A run name MLflow's database takes: cut to NAME_MAX characters (its params keep every override)."""
    return name if len(name) <= NAME_MAX else name[:NAME_MAX - 3] + "..."


def run_name(task_overrides: list[str]) -> str:
    """A run's name: the overrides that change what runs (a store's path in every name hides the factors)."""
    return fit_name(" ".join(o for o in task_overrides if describes_run(o)))


def sweep_key(task_overrides: list[str]) -> str:
    """Identity of a sweep: its task overrides, sorted, without `resume` and `tracking.*` (the same sweep
    resumed, or pointed at another store, is the same sweep)."""
    kept = sorted(o for o in task_overrides if describes_run(o))
    return hashlib.sha256(json.dumps(kept).encode()).hexdigest()[:16]
