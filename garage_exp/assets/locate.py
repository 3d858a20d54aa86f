"""Where the vehicle models and detector weights are, and how to fetch them when they are nowhere.

Lookup order (first hit wins):
- vehicles: $GARAGE_EXP_ASSETS (holding vehicles/flightgear/, or itself a folder of .ac files), then
  ../shared/assets/vehicles/flightgear, then the fetched copy in <cache>/flightgear.
- detector models: $GARAGE_EXP_MODELS, then ../shared/models, then <cache>/models.

Nothing here downloads on its own: `python -m garage_exp.assets fetch` is the only way in.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tarfile
import tempfile
from pathlib import Path

from garage_exp.core import paths
from garage_exp.core.errors import GarageError

ASSETS_ENV = "GARAGE_EXP_ASSETS"
MODELS_ENV = "GARAGE_EXP_MODELS"
DEB_PACKAGE = "flightgear-data-base"
TRANSPORT_DIR = "usr/share/games/flightgear/Scenery/Models/Transport/"
COPYRIGHT_FILE = f"usr/share/doc/{DEB_PACKAGE}/copyright"
# Official Ultralytics COCO weights that `fetch` downloads (the shared models are INT8 exports of these).
MODEL_WEIGHTS = ("yolo11n.pt", "yolov8n.pt", "yolo26n.pt")


def _has_ac(folder: Path) -> bool:
    return folder.is_dir() and any(folder.glob("*.ac"))


def _has_models(folder: Path) -> bool:
    return folder.is_dir() and any(p.suffix == ".pt" or p.name.endswith("_openvino_model") for p in folder.iterdir())


def shared_vehicles_dir() -> Path:
    return paths.shared_dir() / "assets" / "vehicles" / "flightgear"


def fetched_vehicles_dir() -> Path:
    return paths.cache_dir() / "flightgear"


def fetched_models_dir() -> Path:
    return paths.cache_dir() / "models"


def vehicles_dir() -> Path:
    """The folder of FlightGear .ac vehicles; GarageError saying what to set or run when there is none."""
    env = os.environ.get(ASSETS_ENV)
    if env:
        root = Path(env).expanduser()
        for folder in (root / "vehicles" / "flightgear", root):
            if _has_ac(folder):
                return folder
        raise GarageError("holds neither vehicles/flightgear/*.ac nor *.ac files", f"{ASSETS_ENV}={env}")
    for folder in (shared_vehicles_dir(), fetched_vehicles_dir()):
        if _has_ac(folder):
            return folder
    raise GarageError(f"no vehicle models found: set {ASSETS_ENV} to a folder of .ac files or run "
                      "`python -m garage_exp.assets fetch`", "vehicles")


def models_dir() -> Path:
    """The folder of detector models (.pt files or *_openvino_model folders); GarageError when there is none."""
    env = os.environ.get(MODELS_ENV)
    if env:
        folder = Path(env).expanduser()
        if folder.is_dir():
            return folder
        raise GarageError("is not a folder", f"{MODELS_ENV}={env}")
    for folder in (paths.shared_dir() / "models", fetched_models_dir()):
        if _has_models(folder):
            return folder
    raise GarageError(f"no detector models found: set {MODELS_ENV} to a folder of models or run "
                      "`python -m garage_exp.assets fetch`", "models")


def download_deb(workdir: Path, package: str = DEB_PACKAGE) -> Path:
    """`apt-get download` a Debian package (the FlightGear data's by default) into workdir (needs apt lists, not
    root)."""
    if shutil.which("apt-get") is None:
        raise GarageError(f"apt-get is missing: get {package} by hand"
                          + (f" and set {ASSETS_ENV}" if package == DEB_PACKAGE else ""), "fetch")
    proc = subprocess.run(["apt-get", "download", package], cwd=workdir, capture_output=True, text=True)
    debs = sorted(workdir.glob(f"{package}_*.deb"))
    if proc.returncode != 0 or not debs:
        last = (proc.stderr.strip().splitlines() or ["no .deb written"])[-1]
        raise GarageError(f"apt-get download {package} failed ({last}); run `apt-get update` first", "fetch")
    return debs[0]


def extract_transport(deb: Path, dest: Path) -> int:
    """Copy the package's Transport models (.ac and .png only) and its copyright into dest; the file count."""
    dest.mkdir(parents=True, exist_ok=True)

    def target(name: str) -> Path | None:
        if name.startswith(TRANSPORT_DIR) and "/" not in name[len(TRANSPORT_DIR):] \
                and name.lower().endswith((".ac", ".png")):
            return dest / Path(name).name
        return dest / "COPYRIGHT.debian" if name == COPYRIGHT_FILE else None

    return sum(p.suffix.lower() in (".ac", ".png") for p in unpack(deb, target))


def unpack(deb: Path, target) -> list[Path]:
    """Each regular file of the package that `target(path in the package)` names a destination for (None: left
    out), copied there; the destinations written. Streams the data tarball out of `dpkg-deb --fsys-tarfile`, so
    the rest of a large package never touches the disk."""
    written = []
    proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(deb)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE)
    try:
        with tarfile.open(fileobj=proc.stdout, mode="r|*") as tar:
            for member in tar:
                path = target(member.name.removeprefix("./")) if member.isfile() else None
                if path is None:
                    continue
                with open(path, "wb") as out:
                    shutil.copyfileobj(tar.extractfile(member), out)
                written.append(path)
    except tarfile.TarError as exc:
        raise GarageError(f"cannot read the package: {exc}", str(deb)) from None
    finally:
        proc.stdout.close()
        stderr = proc.stderr.read().decode(errors="replace")  # a few lines at most: read once the tar is done
        proc.wait()
    if proc.returncode != 0:
        raise GarageError(f"dpkg-deb failed: {(stderr.strip().splitlines() or ['?'])[-1]}", str(deb))
    return written


def fetch_vehicles(force: bool = False) -> Path:
    """Download and unpack the FlightGear vehicles into the cache (once); their folder."""
    target = fetched_vehicles_dir()
    if _has_ac(target) and not force:
        return target
    with tempfile.TemporaryDirectory(dir=paths.cache_dir()) as tmp:
        work = Path(tmp)
        deb = download_deb(work)
        staged = work / "flightgear"
        count = extract_transport(deb, staged)
        deb.unlink()
        if count == 0 or not _has_ac(staged):
            raise GarageError(f"no .ac files under {TRANSPORT_DIR}", str(deb.name))
        # Rename a complete folder into place so a concurrent reader never sees half of it.
        if target.exists():
            shutil.rmtree(target)
        staged.rename(target)
    return target


def fetch_models(names: tuple[str, ...] = MODEL_WEIGHTS) -> Path:
    """Download the official Ultralytics weights into the cache's models folder; that folder."""
    from garage_exp.core.environment import prepare_environment

    target = fetched_models_dir()
    target.mkdir(parents=True, exist_ok=True)
    prepare_environment(offline=True)  # config dir and fonts under the cache; downloads still go (an explicit call)
    from ultralytics.utils.downloads import attempt_download_asset

    for name in names:
        path = target / name
        if path.exists():
            continue
        try:
            got = Path(attempt_download_asset(str(path)))
        except Exception as exc:  # ultralytics raises ConnectionError and others; one line for the user
            raise GarageError(f"download failed: {str(exc).splitlines()[0]}", name) from None
        if not got.exists():
            raise GarageError("download failed: ultralytics returned no file", name)
        if got.resolve() != path.resolve():
            shutil.copyfile(got, path)  # found in ultralytics' own weights dir: keep a copy where we look
    return target
