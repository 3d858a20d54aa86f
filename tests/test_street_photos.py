"""The loop's second real-photo set (assets/photos.py fetches it from Debian, results/photos.py labels it): the
fetch keeps exactly its photos, the video's frames and the copyrights; every label lies in its photo; the COCO
file scores 32 objects and leaves the 3 ignored ones to crowd regions; a COCO detector finds most of them."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from conftest import require, run_in_process
from PIL import Image

from garage_exp.assets import photos
from garage_exp.core.errors import GarageError
from garage_exp.results.photos import STREET_LABELS, write_street_photos


def fake_deb(tmp: Path, package: str, files: dict[str, str], video_frames: int = 0) -> Path:
    """A .deb holding `files`' members (a few bytes each; the video a real one of `video_frames` frames)."""
    import cv2

    root = tmp / package
    (root / "DEBIAN").mkdir(parents=True)
    (root / "DEBIAN" / "control").write_text(f"Package: {package}\nVersion: 1\nArchitecture: all\n"
                                             "Maintainer: t <t@t>\nDescription: t\n")
    for member, name in files.items():
        path = root / member
        path.parent.mkdir(parents=True, exist_ok=True)
        if name.endswith(".avi"):
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (16, 16))
            for k in range(video_frames):
                writer.write(np.full((16, 16, 3), k % 256, np.uint8))
            writer.release()
        else:
            path.write_bytes(name.encode())
    deb = tmp / f"{package}_1_all.deb"
    subprocess.run(["dpkg-deb", "--build", "-Zgzip", str(root), str(deb)], check=True, capture_output=True)
    return deb


def test_the_fetch_keeps_the_photos_frames_and_copyrights(tmp_path, monkeypatch):
    monkeypatch.setenv("GARAGE_EXP_CACHE", str(tmp_path / "cache"))
    with pytest.raises(GarageError, match="python -m garage_exp.assets ensure"):
        photos.street_photos()
    debs = {p: fake_deb(tmp_path / "debs", p, files, 791) for p, files in photos.PACKAGES.items()}
    monkeypatch.setattr("garage_exp.assets.locate.download_deb", lambda workdir, package: debs[package])
    folder = photos.fetch_street_photos()
    kept = sorted(p.name for p in folder.iterdir())
    assert kept == sorted([*photos.PHOTOS, "COPYRIGHT.node-opencv", "COPYRIGHT.opencv-doc"])  # no video, no temp
    assert (folder / "car1.jpg").read_bytes() == b"car1.jpg"
    frame = np.asarray(Image.open(folder / "vtest_400.png"))
    assert frame.shape == (16, 16, 3) and abs(int(frame.mean()) - 400 % 256) <= 3  # frame 400, read in order
    assert photos.street_photos() == folder


def test_a_package_without_a_photo_or_a_short_video_is_one_line(tmp_path):
    files = dict(photos.PACKAGES["node-opencv"])
    deb = fake_deb(tmp_path, "node-opencv", {k: v for k, v in files.items() if not v.startswith("car2")})
    with pytest.raises(GarageError, match="the package has no usr/share/doc/node-opencv/examples/files/car2.jpg") \
            as err:
        photos.extract(deb, files, tmp_path)
    assert err.value.where == str(deb)
    deb = fake_deb(tmp_path / "short", "opencv-doc", photos.PACKAGES["opencv-doc"], video_frames=10)
    photos.extract(deb, photos.PACKAGES["opencv-doc"], tmp_path)
    with pytest.raises(GarageError, match="frame 10 unreadable"):
        photos.video_frames(tmp_path / "vtest.avi", photos.FRAMES["vtest.avi"], tmp_path)


def test_every_label_lies_in_its_photo_and_the_coco_file_counts_them(tmp_path):
    require("street-photos")
    folder = photos.street_photos()
    assert sorted(STREET_LABELS) == photos.PHOTOS
    for name, (w, h, labelled, ignored) in STREET_LABELS.items():
        with Image.open(folder / name) as im:
            assert im.size == (w, h), name
        for cls, (x1, y1, x2, y2) in [*labelled, *ignored]:
            assert cls in ("car", "pedestrian") and 0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h, (name, x1, y1, x2, y2)
    root = write_street_photos(tmp_path / "street")
    coco = json.loads((root / "coco.json").read_text())
    crowd = [a for a in coco["annotations"] if a["iscrowd"]]
    assert len(coco["images"]) == 11 and len(coco["annotations"]) == 35 and len(crowd) == 3
    assert sum(len((root / "labels" / n).with_suffix(".txt").read_text().split("\n")) - 1
               for n in STREET_LABELS) == 32


@pytest.mark.detect
def test_yolo11n_finds_most_of_the_street_set(tmp_path):
    """The labels line up with what a COCO detector sees: the INT8 yolo11n finds 29 of the 32 objects (measured
    2026-12-06) at a high mAP50; the crowd regions are not required."""
    require("street-photos", "models")
    from garage_exp.verify.app import cli

    root = write_street_photos(tmp_path / "street")
    r = run_in_process([f"data={root / 'coco.json'}", "+label_map.pedestrian=person",
                        "detector.models=[yolo11n_int8_openvino_model]", f"tracking.uri=sqlite:///{tmp_path}/m.db",
                        f"hydra.run.dir={tmp_path}/run"], tmp_path, entry=cli)
    assert r.returncode == 0, r.stderr[-2000:]
    m = json.loads((tmp_path / "run" / "result.json").read_text())["metrics"]
    assert m["targets"] == 32 and m["targets/person"] == 19 and m["targets/vehicle"] == 13
    assert m["recall"] >= 0.85 and m["map50"] >= 0.9


def test_a_loop_without_the_street_photos_says_so_before_any_step_and_its_estimate_runs(tmp_path, monkeypatch):
    from conftest import compose_cfg

    from garage_exp.loop.app import check_loop

    monkeypatch.setenv("GARAGE_EXP_CACHE", str(tmp_path / "empty"))
    check_loop(compose_cfg("estimate=true", config="loop"))  # the estimate needs no photo
    check_loop(compose_cfg("photos=false", config="loop"))
    with pytest.raises(GarageError, match="street photos missing .*`python -m garage_exp.assets ensure`"):
        check_loop(compose_cfg(config="loop"))


def test_an_empty_apt_list_is_updated_once_as_root(tmp_path, monkeypatch):
    """`apt-get download` fails on a fresh machine's empty lists: as root, one `apt-get update`, then again."""
    tries, ran = [], []

    def download(workdir, package):
        tries.append(package)
        if len(tries) == 1:
            raise GarageError("apt-get download opencv-doc failed (E: Unable to locate package)", "fetch")
        return workdir / f"{package}_1_all.deb"

    monkeypatch.setattr("garage_exp.assets.locate.download_deb", download)
    monkeypatch.setattr(photos.subprocess, "run", lambda cmd, **kw: ran.append(cmd))
    monkeypatch.setattr("os.geteuid", lambda: 0)
    assert photos.downloaded(tmp_path, "opencv-doc") == tmp_path / "opencv-doc_1_all.deb"
    assert tries == ["opencv-doc", "opencv-doc"] and ran == [["apt-get", "update", "-qq"]]
    monkeypatch.setattr("os.geteuid", lambda: 1000)
    tries.clear()
    with pytest.raises(GarageError, match="Unable to locate package"):
        photos.downloaded(tmp_path, "opencv-doc")
