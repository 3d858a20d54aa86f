"""Where the project, its outputs, caches and data live."""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]
PLANS_DIR = PROJECT_ROOT / "plans"
OUTPUTS_DIR = PROJECT_ROOT / "outputs"


def cache_dir() -> Path:
    """The user's cache dir for converted meshes and fetched data (XDG convention)."""
    base = os.environ.get("GARAGE_EXP_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "garage_exp"
    )
    path = Path(base)
    path.mkdir(parents=True, exist_ok=True)
    return path


def shared_dir() -> Path:
    """`../shared` beside the checkout (CI and the team machines have it)."""
    return PROJECT_ROOT.parent / "shared"
