"""Keep ultralytics and OpenVINO off the network.

`core.environment.prepare_environment(offline=True)` calls `prepare_offline()`; call it before the first
`import ultralytics` or `import openvino`: both read their settings from the environment and files at import time,
and both would otherwise reach the internet (ultralytics for its font, its connectivity check and analytics;
OpenVINO for GA4 telemetry sent from a background thread).
"""

from __future__ import annotations

import importlib.util
import shutil
import sys
from pathlib import Path

from garage_exp.core.paths import cache_dir
from garage_exp.core.state import STATE

# ultralytics' plot labels ask for these fonts and download them when missing.
FONT_NAMES = ("Arial.ttf", "Arial.Unicode.ttf")
_PREPARED = STATE.cache("core.offline", "process")  # "done" once this process's environment is set


def prepare_offline() -> Path:
    """Set the environment for offline ultralytics/OpenVINO; return ultralytics' settings dir. Idempotent.

    YOLO_CONFIG_DIR defaults to <cache_dir>/ultralytics (a user's own setting is kept), so ultralytics'
    settings and fonts stay out of ~/.config; YOLO_OFFLINE is forced to 1 and YOLO_AUTOINSTALL to False."""
    config_root = Path(STATE.setenv("YOLO_CONFIG_DIR", str(cache_dir() / "ultralytics"), "process", default=True))
    settings_dir = config_root / "Ultralytics"  # ultralytics appends this sub-dir to YOLO_CONFIG_DIR
    if _PREPARED:
        return settings_dir
    STATE.setenv("YOLO_OFFLINE", "1", "process")  # skips ultralytics' DNS check, hub calls and analytics
    # ultralytics pip-installs a missing requirement (onnxslim for an ONNX export) when it finds the network; the
    # set-up ships what the project's exports need, so nothing is installed behind the user's back.
    STATE.setenv("YOLO_AUTOINSTALL", "False", "process")
    _opt_out_of_openvino_telemetry()
    _install_fonts(settings_dir)
    if "ultralytics" in sys.modules:
        # Imported earlier by someone else: YOLO_CONFIG_DIR came too late, so the fonts go where it looks now.
        from ultralytics.utils import USER_CONFIG_DIR, checks

        _install_fonts(Path(USER_CONFIG_DIR))
        checks.AUTOINSTALL = False  # read from the environment at its import
    _PREPARED["done"] = True
    return settings_dir


def _install_fonts(settings_dir: Path) -> None:
    font = dejavu_sans()
    settings_dir.mkdir(parents=True, exist_ok=True)
    for name in FONT_NAMES:
        target = settings_dir / name
        if not target.exists():
            shutil.copyfile(font, target)


def dejavu_sans() -> Path:
    """matplotlib's bundled DejaVuSans.ttf, found without importing matplotlib (a slow import)."""
    spec = importlib.util.find_spec("matplotlib")
    if spec is None or spec.origin is None:
        from garage_exp.core.errors import GarageError

        raise GarageError("matplotlib is not installed; run `make setup`", "garage_exp.perception.detect")
    return Path(spec.origin).parent / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"


def telemetry_consent_file() -> Path:
    """The file openvino_telemetry reads on Linux/macOS: "0" declines, "1" accepts, absent means accept."""
    return Path.home() / "intel" / "openvino_telemetry"


def _opt_out_of_openvino_telemetry() -> None:
    """`import openvino` sends telemetry unless the consent file says "0" or CI=true (its `disable_in_ci`
    check). Write the file when absent, as `opt_in_out --opt_out` would; when it cannot be written or holds an
    opt-in, fall back to CI=true for this process only, because the project must never reach the network."""
    path = telemetry_consent_file()
    try:
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("0")
        declined = path.read_text().strip() == "0"
    except OSError:
        declined = False
    if not declined:
        STATE.setenv("CI", "true", "process")
