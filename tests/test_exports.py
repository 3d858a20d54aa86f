"""The dataset's COCO and KITTI files on synthetic frames (no SAPIEN): read back with pycocotools and a plain KITTI
parser, and each KITTI 3D box projected with its calib's P2 onto the actor's 2D box."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from garage_exp.exports import DatasetExports, FrameGeometry, coco, kitti
from garage_exp.perception.groundtruth import ground_truth, world_corners
from garage_exp.render import Frame
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import CameraSpec, Entity, Pose, Scene

W, H = 640, 480
CAR = (4.5, 1.8, 1.5)


def actor(name, pose, extent=CAR, model="sedan_black", kind="vehicle"):
    return Entity(name, "parked", pose, model=model, extent=extent, static=False, kind=kind)


def frame_of(scene: Scene, ego: Pose, spec: CameraSpec) -> tuple[Frame, dict, dict]:
    """The frame a renderer would give, its actors' silhouettes painted as their projected 3D boxes' convex hulls,
    nearer actors over farther ones; (frame, silhouettes, ids)."""
    import cv2

    frame = Frame(spec.name, np.zeros((H, W, 3), np.uint8), np.zeros((H, W), np.int32),
                  camera_to_world(ego, spec), lens_of(spec), {e.name: e.pose for e in scene.entities})
    silhouettes, ids, depths = {}, {}, {}
    for k, e in enumerate(scene.entities):
        uv, depth = frame.project(world_corners(e, e.pose))
        assert np.all(depth > 0.5), e.name  # the stand-in silhouette needs every corner in front
        mask = np.zeros((H, W), np.uint8)
        # Pixel (c, r) spans [c, c+1): shift by half a pixel so cv2 fills the pixels whose centres are inside.
        cv2.fillConvexPoly(mask, cv2.convexHull(np.round((uv - 0.5) * 16).astype(np.int32)), 1, shift=4)
        if mask.any():
            silhouettes[e.name], ids[e.name], depths[e.name] = mask.astype(bool), k + 1, depth.mean()
    for name in sorted(silhouettes, key=lambda n: -depths[n]):
        frame.ids[silhouettes[name]] = ids[name]
    return frame, silhouettes, ids


def read_kitti_label(path) -> list[dict]:
    """KITTI's devkit reading of a label_2 file: 15 whitespace-separated fields per object."""
    out = []
    for line in path.read_text().splitlines():
        f = line.split()
        assert len(f) == 15, line
        out.append({"type": f[0], "truncated": float(f[1]), "occluded": int(f[2]), "alpha": float(f[3]),
                    "bbox": [float(v) for v in f[4:8]], "hwl": [float(v) for v in f[8:11]],
                    "xyz": [float(v) for v in f[11:14]], "ry": float(f[14])})
    return out


def read_kitti_calib(path) -> dict[str, np.ndarray]:
    rows = dict(line.split(":", 1) for line in path.read_text().splitlines() if line)
    return {k: np.array([float(v) for v in s.split()]) for k, s in rows.items()}


def devkit_corners(hwl, xyz, ry) -> np.ndarray:
    """The 8 corners as KITTI's devkit (computeBox3D) builds them: x along the length, y up is -h."""
    h, w, l = hwl
    x = [l / 2, l / 2, -l / 2, -l / 2, l / 2, l / 2, -l / 2, -l / 2]
    y = [0, 0, 0, 0, -h, -h, -h, -h]
    z = [w / 2, -w / 2, -w / 2, w / 2, w / 2, -w / 2, -w / 2, w / 2]
    rot = np.array([[math.cos(ry), 0, math.sin(ry)], [0, 1, 0], [-math.sin(ry), 0, math.cos(ry)]])
    return (rot @ np.array([x, y, z])).T + np.array(xyz)


def in_image_bounds(uv: np.ndarray, width: int = W, height: int = H) -> list[float]:
    """Bounds (x1, y1, x2, y2) of the points' convex hull clipped to the image (Sutherland-Hodgman)."""
    import cv2

    poly = [tuple(p) for p in cv2.convexHull(uv.astype(np.float32))[:, 0].astype(float)]
    for axis, limit, keep_below in ((0, 0.0, False), (0, width, True), (1, 0.0, False), (1, height, True)):
        inside = (lambda p: p[axis] <= limit) if keep_below else (lambda p: p[axis] >= limit)
        out = []
        for a, b in zip(poly, poly[1:] + poly[:1]):
            if inside(a):
                out.append(a)
            if inside(a) != inside(b):
                t = (limit - a[axis]) / (b[axis] - a[axis])
                out.append((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])))
        poly = out
    xs, ys = zip(*poly)
    return [min(xs), min(ys), max(xs), max(ys)]


def p2_project(p2: np.ndarray, pts: np.ndarray) -> np.ndarray:
    uvw = np.hstack([pts, np.ones((8, 1))]) @ p2.reshape(3, 4).T
    return uvw[:, :2] / uvw[:, 2:]


# A garage-like frame: a car 10 m ahead in the lane (partly behind a nearer crossing car), a van crossing, a
# car cut by the right image edge, a person; plus a car wholly behind the van (never labelled).
def busy_scene() -> Scene:
    return Scene("s", [
        actor("ahead", Pose(12.0, -0.5, 0.0, 0.0)),
        actor("crossing", Pose(8.0, 3.2, 0.0, 90.0), extent=(5.0, 2.0, 2.2), model="van_silver"),
        actor("hidden", Pose(14.0, 3.5, 0.0, 90.0), extent=(3.5, 1.6, 1.4)),
        actor("edge", Pose(6.0, -3.4, 0.0, 180.0), model="pickupred1"),
        actor("walker", Pose(6.0, -0.3, 0.0, 200.0), extent=(0.3, 0.5, 1.7), model=None, kind="person"),
    ])


FRONT = CameraSpec("front", Pose(0.3, 0.0, 1.55), width=W, height=H)
PITCHED = CameraSpec("wide", Pose(0.3, 0.0, 1.55, 15.0), pitch=10.0, fovy=90.0, width=W, height=H)
EGO = Pose(0.0, 0.0, 0.0, 0.0)


@pytest.fixture(params=["front", "pitched_yawed"])
def exported(request, tmp_path):
    """The busy frame exported, from a level front camera and from a pitched, yawed one on a turned ego."""
    spec, ego = (FRONT, EGO) if request.param == "front" else (PITCHED, Pose(0.0, 0.4, 0.0, -8.0))
    scene = busy_scene()
    frame, silhouettes, ids = frame_of(scene, ego, spec)
    truth = ground_truth(frame, silhouettes, scene, ids)
    writer = DatasetExports(tmp_path / "dataset")
    writer.add(f"0000_{spec.name}", spec.name, frame.rgb, truth, scene, FrameGeometry.of(frame))
    writer.finish()
    return tmp_path / "dataset", truth, frame, scene


def test_the_scene_has_what_the_exports_must_handle(exported):
    _, truth, _, _ = exported
    by = {t.name: t for t in truth}
    assert by["hidden"].visible_pixels == 0  # wholly behind the van: in view, not labelled
    assert 0 < by["ahead"].visible_fraction < 0.85 or 0 < by["walker"].visible_fraction < 0.85
    assert by["edge"].truncation > 0.05


def test_coco_reads_back_with_pycocotools(exported):
    root, truth, _, _ = exported
    gt = COCO(str(root / "coco.json"))
    [img] = gt.loadImgs(gt.getImgIds())
    assert (img["file_name"], img["width"], img["height"]) == (f"0000_{img['camera']}.png", W, H)
    assert (root / "images" / img["file_name"]).exists()
    assert {c["name"]: c["id"] for c in gt.loadCats(gt.getCatIds())} == {"person": 1, "car": 3, "bus": 6,
                                                                         "truck": 8}
    anns = {a["attributes"]["name"]: a for a in gt.loadAnns(gt.getAnnIds(imgIds=[img["id"]]))}
    labelled = {t.name: t for t in truth if t.visible_pixels > 0}
    assert set(anns) == set(labelled) and "hidden" not in anns
    assert {n: a["category_id"] for n, a in anns.items()} == {"ahead": 3, "crossing": 8, "edge": 8, "walker": 1}
    for name, t in labelled.items():
        a = anns[name]
        x1, y1, x2, y2 = t.full_box
        assert a["bbox"] == [x1, y1, x2 - x1, y2 - y1] and a["area"] == t.visible_pixels and a["iscrowd"] == 0
        attrs = a["attributes"]
        assert attrs["visible_fraction"] == pytest.approx(t.visible_fraction, abs=1e-6)
        assert attrs["occlusion"] == t.occlusion and attrs["kitti_difficulty"] == t.kitti
        assert attrs["truncation"] == pytest.approx(t.truncation, abs=1e-4)
        assert attrs["distance"] == pytest.approx(t.distance, abs=1e-4)
        vx1, vy1, vx2, vy2 = t.visible_box
        assert attrs["visible_bbox"] == [vx1, vy1, vx2 - vx1, vy2 - vy1]


def test_coco_ground_truth_scores_itself_perfectly_in_cocoeval(exported):
    """The file works in COCO's own evaluation: the ground truth given back as detections scores AP 1."""
    root, _, _, _ = exported
    gt = COCO(str(root / "coco.json"))
    dets = gt.loadRes([{"image_id": a["image_id"], "category_id": a["category_id"], "bbox": a["bbox"],
                        "score": 1.0} for a in gt.dataset["annotations"]])
    ev = COCOeval(gt, dets, "bbox")
    ev.evaluate()
    ev.accumulate()
    ev.summarize()
    assert ev.stats[0] == pytest.approx(1.0)


def test_coco_category_ids_are_cocos_own():
    from ultralytics.data.converter import coco80_to_coco91_class

    from garage_exp.results.labels import COCO_IDS, coco_names

    to91 = coco80_to_coco91_class()
    names = coco_names()
    for c in coco.CATEGORIES:
        assert to91[COCO_IDS[c["name"]]] == c["id"] and names[COCO_IDS[c["name"]]] == c["name"]


def test_citypersons_bins():
    assert [coco.citypersons_bin(v) for v in (1.0, 0.9, 0.89, 0.65, 0.64, 0.2, 0.19, 0.0)] == [
        "bare", "bare", "partial", "partial", "heavy", "heavy", "beyond_heavy", "beyond_heavy"]


def test_kitti_reads_back_and_each_3d_box_projects_onto_its_2d_box(exported):
    root, truth, frame, _ = exported
    kitti_root = root / "kitti"
    assert (kitti_root / "ImageSets" / "train.txt").read_text() == "000000\n"
    assert (kitti_root / "frames.csv").read_text().splitlines()[1] == f"000000,0000_{frame.camera}"
    image = Image.open(kitti_root / "image_2" / "000000.png")
    assert image.size == (W, H)
    calib = read_kitti_calib(kitti_root / "calib" / "000000.txt")
    assert list(calib) == ["P0", "P1", "P2", "P3", "R0_rect", "Tr_velo_to_cam", "Tr_imu_to_velo"]
    assert [len(v) for v in calib.values()] == [12, 12, 12, 12, 9, 12, 12]
    labels = read_kitti_label(kitti_root / "label_2" / "000000.txt")
    labelled = [t for t in truth if t.visible_pixels > 0]
    assert [lb["type"] for lb in labels] == [{"ahead": "Car", "crossing": "Van", "edge": "Truck",
                                              "walker": "Pedestrian"}[t.name] for t in labelled]
    for lb, t in zip(labels, labelled):
        assert lb["bbox"] == list(t.full_box)
        assert lb["occluded"] == t.occlusion and lb["truncated"] == pytest.approx(t.truncation, abs=0.005)
        uv = p2_project(calib["P2"], devkit_corners(lb["hwl"], lb["xyz"], lb["ry"]))
        # The silhouettes here are the projected boxes' hulls: the bounds of the hull's part inside the image are
        # the 2D box to the pixel (rounding of the 4-decimal label and of the hull's pixel edges).
        assert in_image_bounds(uv) == pytest.approx(lb["bbox"], abs=1.0), (t.name, lb["bbox"])
        # alpha is rotation_y less the ray's angle, as KITTI defines it.
        x, _, z = lb["xyz"]
        assert math.cos(lb["alpha"] - (lb["ry"] - math.atan2(x, z))) == pytest.approx(1.0, abs=1e-6)
    assert labels[[t.name for t in labelled].index("edge")]["truncated"] > 0.05


def test_kitti_box_is_the_world_box_seen_by_the_camera(exported):
    """The 8 devkit corners through P2 are the 8 world corners through the project's own camera projection."""
    root, truth, frame, scene = exported
    calib = read_kitti_calib(root / "kitti" / "calib" / "000000.txt")
    for lb, t in zip(read_kitti_label(root / "kitti" / "label_2" / "000000.txt"),
                     [t for t in truth if t.visible_pixels > 0]):
        e = scene.entity(t.name)
        ours, _ = frame.project(world_corners(e, e.pose))
        theirs = p2_project(calib["P2"], devkit_corners(lb["hwl"], lb["xyz"], lb["ry"]))
        gap = np.linalg.norm(ours[:, None] - theirs[None], axis=2)  # px, each of ours to each of theirs
        assert gap.min(axis=0).max() < 0.05 and gap.min(axis=1).max() < 0.05, (t.name, gap.min(axis=0))
        assert lb["hwl"] == pytest.approx([e.extent[2], e.extent[1], e.extent[0]], abs=1e-4)


def test_kitti_frame_conventions():
    """Level front camera 1.55 m up: a car 10 m ahead facing away sits at z 10 (its centre), y 1.55 (its
    bottom), rotation_y -pi/2; one crossing to the camera's right has rotation_y 0; facing the camera +pi/2."""
    cam = camera_to_world(EGO, FRONT)
    ahead = kitti.box3d(actor("a", Pose(10.3, 0.0, 0.0, 0.0)), Pose(10.3, 0.0, 0.0, 0.0), cam)
    assert ahead.location == pytest.approx((0.0, 1.55, 10.0)) and ahead.rotation_y == pytest.approx(-math.pi / 2)
    assert ahead.dimensions == pytest.approx((1.5, 1.8, 4.5)) and ahead.alpha == pytest.approx(-math.pi / 2)
    right = kitti.box3d(actor("r", Pose()), Pose(10.3, -2.0, 0.0, 270.0), cam)
    assert right.location == pytest.approx((2.0, 1.55, 10.0)) and right.rotation_y == pytest.approx(0.0, abs=1e-9)
    facing = kitti.box3d(actor("f", Pose()), Pose(10.3, 0.0, 0.0, 180.0), cam)
    assert facing.rotation_y == pytest.approx(math.pi / 2)
    # A camera looking straight down keeps its heading: the car below, nose along the camera's yaw, has ry -pi/2.
    down = camera_to_world(Pose(0.0, 0.0, 0.0, 30.0), CameraSpec("down", Pose(0.0, 0.0, 3.0), pitch=90.0))
    below = kitti.box3d(actor("b", Pose()), Pose(0.0, 0.0, 0.0, 30.0), down)
    assert below.location == pytest.approx((0.0, 3.0, 0.0), abs=1e-9)
    assert below.rotation_y == pytest.approx(-math.pi / 2)
    # A level camera's P2 is [K | 0], as KITTI's.
    lens = lens_of(FRONT)
    fx, fy, cx, cy = lens.fx, lens.fy, lens.cx, lens.cy
    assert kitti.projection(cam, lens.K) == pytest.approx(
        np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0]]))


def test_the_three_formats_label_the_same_actors(exported):
    root, truth, _, _ = exported
    yolo = (root / "labels" / next((root / "labels").iterdir()).name).read_text().splitlines()
    coco_json = json.loads((root / "coco.json").read_text())
    labels = read_kitti_label(root / "kitti" / "label_2" / "000000.txt")
    assert len(yolo) == len(coco_json["annotations"]) == len(labels) == sum(t.visible_pixels > 0 for t in truth)
    for line, ann, lb in zip(yolo, coco_json["annotations"], labels):
        cls, xc, yc, w, h = map(float, line.split())
        x, y, bw, bh = ann["bbox"]
        assert (xc * W, yc * H, w * W, h * H) == pytest.approx((x + bw / 2, y + bh / 2, bw, bh), abs=1e-3)
        assert lb["bbox"] == pytest.approx([x, y, x + bw, y + bh])
        assert {0: 1, 2: 3, 5: 6, 7: 8}[int(cls)] == ann["category_id"]


def test_an_actor_without_a_box_gets_kittis_unknown_3d_fields():
    from garage_exp.perception.groundtruth import VehicleTruth

    t = VehicleTruth("blob", "parked", 50, 100, 0.5, (10, 10, 20, 20), (5, 5, 20, 20), 7.0, 0.0, 1, "moderate")
    line = kitti.label_line("car", t, None).split()
    assert line[0] == "Car" and line[3] == "-10.0000"
    assert [float(v) for v in line[8:]] == [-1, -1, -1, -1000, -1000, -1000, -10]


def test_docs_say_the_codes_ids_and_types():
    from conftest import ROOT

    page = (ROOT / "docs" / "outputs.md").read_text()
    assert ", ".join(f"{c['name']} {c['id']}" for c in coco.CATEGORIES) in page
    assert "Car for cars and SUVs, Van, Truck for pickups and trucks, Pedestrian, Misc for buses" in page
    assert kitti.KITTI_TYPES == {"car": "Car", "suv": "Car", "van": "Van", "pickup": "Truck", "truck": "Truck",
                                 "bus": "Misc", "person": "Pedestrian"}


def test_the_show_command_draws_a_frame_from_its_files(exported, tmp_path, capsys):
    from garage_exp.exports.__main__ import main

    root, truth, frame, _ = exported
    out = tmp_path / "check.png"
    assert main([str(root), "-o", str(out)]) == 0
    drawn = np.asarray(Image.open(out)).astype(int)
    red = (np.abs(drawn - [230, 30, 30]).sum(axis=2) < 60)
    green = (np.abs(drawn - [0, 220, 0]).sum(axis=2) < 60)
    assert red.sum() > 500 and green.sum() > 500
    # The 3D box of the walker (whole, in the middle of the frame) is drawn around its 2D box's corners.
    x1, y1, x2, y2 = next(t for t in truth if t.name == "walker").full_box
    assert red[max(y1 - 3, 0):y1 + 4, x1 - 3:x2 + 4].any() and red[y2 - 4:y2 + 3, x1 - 3:x2 + 4].any()


def test_the_show_command_says_what_is_wrong_in_one_line(exported, tmp_path, capsys):
    from garage_exp.exports.__main__ import main

    assert main([str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    root = exported[0]
    (root / "kitti" / "label_2" / "000000.txt").write_text("Car 0.0 0\n")
    assert main([str(root), "-o", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert "label_2/000000.txt:1" in err and "\n" not in err and not (tmp_path / "x.png").exists()


def test_the_show_command_names_a_missing_kitti_file(exported, tmp_path, capsys):
    from garage_exp.exports.__main__ import main

    root = exported[0]
    (root / "kitti" / "calib" / "000000.txt").unlink()
    assert main([str(root), "-o", str(tmp_path / "x.png")]) == 2
    assert capsys.readouterr().err.strip().endswith("calib/000000.txt: missing")
