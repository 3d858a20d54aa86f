import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PYTHON = sys.executable

# Tests never reach for the network and never write into the user's MLflow store.
os.environ.setdefault("YOLO_OFFLINE", "1")
os.environ.pop("MLFLOW_TRACKING_URI", None)

from garage_exp.detect import prepare_offline  # noqa: E402

prepare_offline()


@pytest.fixture
def mlflow_uri(tmp_path) -> str:
    return f"sqlite:///{tmp_path / 'mlflow.db'}"


def run_app(args: list[str], tmp_path: Path, env: dict | None = None, timeout: int = 600):
    """Run `python -m garage_exp` in a subprocess with outputs under tmp_path."""
    import subprocess

    full_env = {**os.environ, **(env or {})}
    cmd = [PYTHON, "-m", "garage_exp", *args,
           f"hydra.run.dir={tmp_path}/run", f"hydra.sweep.dir={tmp_path}/sweep"]
    return subprocess.run(cmd, cwd=tmp_path, env=full_env, capture_output=True, text=True, timeout=timeout)
