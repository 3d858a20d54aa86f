"""Real street photos for the detectors' forgetting check (the loop's second real-photo set, results/photos.py
labels them): sample images two Debian packages ship, fetched once into the cache by `python -m garage_exp.assets
ensure` (`make data`), nothing downloaded at run time.

- opencv-doc (OpenCV's samples; Debian lists them Apache-2.0 and BSD-3-Clause): three street scenes with cars and
  people from its text-detection samples, a motion-blurred car, two frames of people playing basketball, and three
  frames of `vtest.avi` (a campus seen from above: walking people, a van, a car).
- node-opencv (its examples, Expat): two cars seen from the side.
Each package's copyright file is kept beside the photos.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

from garage_exp.core import paths
from garage_exp.core.errors import GarageError

DOC = "usr/share/doc"
PACKAGES = {
    "opencv-doc": {f"{DOC}/opencv-doc/examples/text/scenetext01.jpg": "scenetext01.jpg",
                   f"{DOC}/opencv-doc/examples/text/scenetext05.jpg": "scenetext05.jpg",
                   f"{DOC}/opencv-doc/examples/text/scenetext06.jpg": "scenetext06.jpg",
                   f"{DOC}/opencv-doc/examples/data/licenseplate_motion.jpg": "licenseplate_motion.jpg",
                   f"{DOC}/opencv-doc/examples/data/basketball1.png": "basketball1.png",
                   f"{DOC}/opencv-doc/examples/data/basketball2.png": "basketball2.png",
                   f"{DOC}/opencv-doc/examples/data/vtest.avi": "vtest.avi",
                   f"{DOC}/opencv-doc/copyright": "COPYRIGHT.opencv-doc"},
    "node-opencv": {f"{DOC}/node-opencv/examples/files/car1.jpg": "car1.jpg",
                    f"{DOC}/node-opencv/examples/files/car2.jpg": "car2.jpg",
                    f"{DOC}/node-opencv/copyright": "COPYRIGHT.node-opencv"},
}
FRAMES = {"vtest.avi": {0: "vtest_000.png", 400: "vtest_400.png", 790: "vtest_790.png"}}  # video -> its frames kept
PHOTOS = sorted([n for files in PACKAGES.values() for n in files.values()
                 if not n.startswith("COPYRIGHT") and n not in FRAMES] + [n for f in FRAMES.values() for n in f.values()])


def street_dir() -> Path:
    return paths.cache_dir() / "photos" / "street"


def street_photos() -> Path:
    """The folder holding every street photo; GarageError saying how to fetch them when one is missing."""
    folder = street_dir()
    missing = [n for n in PHOTOS if not (folder / n).is_file()]
    if missing:
        raise GarageError(f"{len(missing)} of {len(PHOTOS)} street photos missing ({missing[0]}, ...): "
                          "`python -m garage_exp.assets ensure` (`make data`) fetches them from Debian", str(folder))
    return folder


def fetch_street_photos() -> Path:
    """Download the two packages, keep only the photos (and the video's frames) and the copyrights; the folder."""
    folder = street_dir()
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder.parent) as tmp:
        for package, files in PACKAGES.items():
            extract(downloaded(Path(tmp), package), files, Path(tmp))
            for name in files.values():
                if name in FRAMES:
                    video_frames(Path(tmp) / name, FRAMES[name], Path(tmp))
        for name in [*PHOTOS, *(n for f in PACKAGES.values() for n in f.values() if n.startswith("COPYRIGHT"))]:
            shutil.move(str(Path(tmp) / name), folder / name)
    return street_photos()


def downloaded(workdir: Path, package: str) -> Path:
    """The package's .deb in workdir; on a machine whose apt lists are empty (a fresh one), as root, after
    `apt-get update` (the set-up's other apt steps may all have been skipped as done)."""
    import os

    from garage_exp.assets.locate import download_deb

    try:
        return download_deb(workdir, package)
    except GarageError:
        if os.geteuid() != 0 or shutil.which("apt-get") is None:
            raise
        subprocess.run(["apt-get", "update", "-qq"], capture_output=True, timeout=600)
        return download_deb(workdir, package)


def extract(deb: Path, files: dict[str, str], dest: Path) -> None:
    """The package's members named in `files` (path in the package -> file name) into dest (locate.unpack: only
    these few files of opencv-doc's ~100 MB touch the disk)."""
    from garage_exp.assets.locate import unpack

    written = {p.name for p in unpack(deb, lambda name: dest / files[name] if name in files else None)}
    missing = sorted(member for member, name in files.items() if name not in written)
    if missing:
        raise GarageError(f"the package has no {missing[0]} (another version?)", str(deb))


def video_frames(video: Path, frames: dict[int, str], dest: Path) -> None:
    """The video's frames numbered in `frames` as PNGs (read in order: seeking is not exact in every codec)."""
    import cv2

    capture = cv2.VideoCapture(str(video))
    try:
        for k in range(max(frames) + 1):
            ok, image = capture.read()
            if not ok:
                raise GarageError(f"frame {k} unreadable (the video has fewer frames?)", str(video))
            if k in frames:
                cv2.imwrite(str(dest / frames[k]), image)
    finally:
        capture.release()
