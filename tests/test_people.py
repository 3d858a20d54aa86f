"""People: anny bodies as GLB files, ground truth and scoring for a person, mixed classes in matching and the
dataset. No SAPIEN; building bodies needs anny (its model loads once per session, about a second once its own
cache exists, about a minute or more the first time on a machine)."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from garage_exp.assets import people
from garage_exp.perception.detect import Detections, GTBox, score_target
from garage_exp.core.errors import GarageError
from garage_exp.perception.groundtruth import ground_truth, local_box, mask_box, world_corners
from garage_exp.render import Frame
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.lenses import lens_of
from garage_exp.results.labels import COCO_IDS, DatasetWriter
from garage_exp.results.table import frame_row, summarise
from garage_exp.scene.description import CameraSpec, Entity, Mesh, Pose, Scene


@pytest.fixture(scope="session")
def library(tmp_path_factory):
    """A library in a temp folder; anny's own cache stays where the machine keeps it (built once)."""
    return people.PeopleLibrary(tmp_path_factory.mktemp("people"))


@pytest.fixture(scope="session")
def adult(library):
    return library.body("adult", height=1.8, pose="standing")


@pytest.fixture(scope="session")
def child(library):
    return library.body("child", height=1.15, pose="walking", clothing={"outfit": "bright", "shirt": "red"})


def load(model) -> "trimesh.Scene":  # noqa: F821
    import trimesh

    return trimesh.load(model.glb, force="scene")


def test_bodies_have_the_asked_height_feet_on_the_floor_centred(adult, child):
    for model, asked in ((adult, 1.8), (child, 1.15)):
        lo, hi = load(model).bounds
        assert abs(hi[2] - lo[2] - asked) < (0.02 if model.pose == "standing" else 0.06), model
        assert abs(lo[2]) < 1e-6  # feet at z = 0
        assert np.allclose((lo[:2] + hi[:2]) / 2, 0.0, atol=1e-6)  # centred on x = y = 0, like the vehicles
        assert np.allclose(hi - lo, model.extent, atol=1e-3)
    assert abs(adult.height - 1.8) < 0.02
    assert 1.1 <= child.height <= 1.15  # mid-stride a body stands a little lower
    assert child.length > 1.5 * adult.length * child.height / adult.height  # a stride is long along x


def test_bodies_face_plus_x(adult):
    """The toes point to +x (they are ahead of the heels) and the face is ahead of the back of the head."""
    scene = load(adult)
    shoes = scene.geometry["shoes"].vertices
    skin = scene.geometry["skin"].vertices
    hair = scene.geometry["hair"].vertices
    assert shoes[:, 0].max() > 0.1 and shoes[:, 0].max() > -shoes[:, 0].min() + 0.03
    face = skin[skin[:, 2] > adult.height - 0.2]  # the face: skin in the head's top 20 cm
    assert face[:, 0].mean() > hair[hair[:, 2] > adult.height - 0.2][:, 0].mean() + 0.03
    assert adult.width < 0.7  # arms down: no wider than the shoulders and the hands beside the hips


def test_glb_round_trip_keeps_the_regions_and_their_colours(adult, child):
    for model in (adult, child):
        scene = load(model)
        assert set(scene.geometry) == set(people.REGIONS)
        for region, mesh in scene.geometry.items():
            colour = np.asarray(mesh.visual.material.baseColorFactor[:3], float)
            expected = np.asarray(model.colours[region], float)
            assert np.allclose(colour, expected, atol=1.0), (region, colour, expected)
        total = sum(len(m.faces) for m in scene.geometry.values())
        assert total > 20000  # the whole body, not a part
    assert child.colours["shirt"] == people.PALETTE["red"] and child.colours["shoes"] == people.PALETTE["white"]
    sidecar = json.loads(Path(child.glb).with_suffix(".json").read_text())
    assert sidecar["age_group"] == "child" and sidecar["pose"] == "walking"
    assert sidecar["height"] == child.height and sidecar["colours"]["shirt"] == list(people.PALETTE["red"])


def test_cache_hit_does_not_rebuild(library, adult, monkeypatch):
    def fail(*_):
        raise AssertionError("rebuilt a cached body")

    monkeypatch.setattr(people, "build_body", fail)
    again = library.body("adult", height=1.8)
    assert again == adult
    fresh = people.PeopleLibrary(library.root).body("adult", height=1.8)  # another process, same cache
    assert fresh.glb == adult.glb
    with pytest.raises(AssertionError, match="rebuilt"):
        library.body("adult", height=1.81)  # another parameter set is another file


def test_every_parameter_set_has_its_own_file():
    variants = ({}, {"pose": "walking"}, {"clothing": "dark"}, {"build": "slim"}, {"clothing": {"shirt": [1, 2, 3]}})
    names = {people.make_spec(height=1.8, **kwargs).digest() for kwargs in variants}
    assert len(names) == 5
    assert len({s.digest() for s in people.PREBUILT}) == len(people.PREBUILT)
    assert any(s.age_group == "child" and 1.1 <= s.height <= 1.3 for s in people.PREBUILT)
    assert {s.pose for s in people.PREBUILT} == set(people.POSES)


@pytest.mark.parametrize("kwargs, where", [
    ({"age_group": "baby"}, "people.age_group"), ({"height": 2.5}, "people.height"),
    ({"age_group": "child", "height": 1.8}, "people.height"), ({"build": "huge"}, "people.build"),
    ({"pose": "running"}, "people.pose"), ({"clothing": "tuxedo"}, "people.clothing"),
    ({"clothing": {"hat": "red"}}, "people.clothing"), ({"clothing": {"shirt": "mauve"}}, "people.clothing.shirt"),
    ({"clothing": {"shirt": [300, 0, 0]}}, "people.clothing.shirt"),
])
def test_bad_body_parameters_name_the_key(kwargs, where):
    with pytest.raises(GarageError) as err:
        people.make_spec(**kwargs)
    assert err.value.where == where
    with pytest.raises(GarageError) as err:
        people.make_spec(**kwargs, where="case.actors.child")
    assert err.value.where == where.replace("people", "case.actors.child")


# --- ground truth and scoring for a person ---------------------------------------------------------------------

W, H = 640, 480


def person_entity(model, pose: Pose, name: str = "walker") -> Entity:
    return Entity(name, "target", pose, [Mesh(model.glb)], model=model.name, extent=model.extent, static=False,
                  kind="person")


def test_ground_truth_of_a_person(adult):
    """A person 8 m ahead: its box is its extent (feet at z=0), the projected box fits the image, KITTI easy."""
    pose = Pose(8.0, 0.0, 0.0, 180.0)
    entity = person_entity(adult, pose)
    lo, hi = local_box(entity)
    assert np.allclose(hi - lo, adult.extent) and lo[2] == 0.0
    corners = world_corners(entity, pose)
    assert corners[:, 2].min() == 0.0 and corners[:, 2].max() == pytest.approx(adult.height)
    spec = CameraSpec("front", Pose(0.0, 0.0, 1.5), width=W, height=H)
    frame = Frame("front", np.zeros((H, W, 3), np.uint8), np.zeros((H, W), np.int32), camera_to_world(Pose(), spec),
                  lens_of(spec), {"walker": pose})
    uv, depth = frame.project(corners)
    x1, y1 = np.floor(uv.min(axis=0)).astype(int)
    x2, y2 = np.ceil(uv.max(axis=0)).astype(int)
    silhouette = np.zeros((H, W), bool)
    silhouette[y1:y2, x1:x2] = True
    frame.ids[silhouette] = 5
    frame.ids[y1:(y1 + y2) // 2, x1:x2] = 9  # the upper half hidden
    scene = Scene("s", [entity])
    (truth,) = ground_truth(frame, {"walker": silhouette}, scene, {"walker": 5})
    assert truth.kind == "person" and truth.role == "target"
    assert truth.full_box == mask_box(silhouette) and truth.box_height == y2 - y1 > 40
    assert truth.visible_fraction == pytest.approx(0.5, abs=0.02) and truth.kitti == "moderate"
    assert truth.truncation == 0.0 and truth.distance == pytest.approx(8.0, abs=0.3)
    assert scene.actors() == [entity] and scene.people() == [entity] and scene.vehicles() == []


# --- mixed classes ------------------------------------------------------------------------------------------------

def dets(model: str, *rows: tuple) -> Detections:
    return Detections(np.array([r[:4] for r in rows], np.float32).reshape(-1, 4),
                      np.array([r[4] for r in rows], np.float32), [r[5] for r in rows], model)


def test_a_person_target_is_matched_by_person_classes_and_a_car_by_vehicle_classes():
    walker = GTBox((100, 100, 140, 220), (100, 100, 140, 220), kind="person")
    car = GTBox((300, 150, 500, 250), (300, 150, 500, 250))
    models = [dets("a", (100, 100, 140, 220, 0.8, "person"), (300, 150, 500, 250, 0.9, "car")),
              dets("b", (100, 100, 140, 220, 0.7, "car"), (300, 150, 500, 250, 0.6, "person"))]  # classes swapped
    on_walker = score_target(models, walker, [walker, car])
    assert on_walker.per_model == pytest.approx([0.8, 0.0])
    # Model a: both right, no false positive. Model b: a car on the person and a person on the car are both false.
    assert on_walker.false_positives_per_model == [0, 2]
    on_car = score_target(models, car, [walker, car])
    assert on_car.per_model == pytest.approx([0.9, 0.0]) and on_car.false_positives_per_model == [0, 2]
    # Person classes come from the config like vehicle classes.
    assert score_target(models, walker, [walker, car], person_classes=("car",)).per_model[1] == pytest.approx(0.7)


def test_a_person_detection_without_a_person_in_truth_is_still_a_false_positive():
    """Vehicle-only scenes count a person detection as a false positive, as before people existed."""
    car = GTBox((300, 150, 500, 250))
    models = [dets("a", (300, 150, 500, 250, 0.9, "car"), (10, 10, 50, 90, 0.6, "person"),
                   (600, 0, 639, 90, 0.5, "bicycle"))]
    assert score_target(models, car, [car]).false_positives == 2
    walker = GTBox((10, 10, 50, 90), kind="person")
    assert score_target(models, car, [car, walker]).false_positives == 1  # the bicycle only


def test_dataset_labels_a_person_with_coco_id_0(tmp_path, adult):
    scene = Scene("s", [person_entity(adult, Pose(8.0, 0.0, 0.0)), Entity("car", "parked", Pose(), model="xx",
                                                                          extent=(4.5, 1.8, 1.5), static=False)])
    truth = [SimpleNamespace(name="walker", kind="person", visible_box=(10, 20, 30, 80), visible_pixels=300,
                             full_box=(10, 20, 30, 80)),
             SimpleNamespace(name="car", kind="vehicle", visible_box=(100, 100, 300, 200), visible_pixels=900,
                             full_box=(100, 100, 300, 200))]
    writer = DatasetWriter(tmp_path)
    writer.add("0000_front", np.zeros((H, W, 3), np.uint8), truth, scene)
    rows = [line.split() for line in (tmp_path / "labels" / "0000_front.txt").read_text().splitlines()]
    assert [int(r[0]) for r in rows] == [0, COCO_IDS["car"]] and COCO_IDS["person"] == 0
    assert float(rows[0][3]) == pytest.approx(20 / W) and float(rows[0][4]) == pytest.approx(60 / H)


def test_frame_rows_name_the_target_kind_only_in_scenes_with_people():
    shot = SimpleNamespace(index=0, label="adult", position=8.0, ego=Pose(), target="walker")
    truth = SimpleNamespace(distance=8.0, visible_fraction=1.0, visible_pixels=100, full_box=(0, 0, 10, 50),
                            truncation=0.0, kitti="easy", occluder="none")
    score = SimpleNamespace(per_model=[0.8], composite=0.8, detected=True, false_positives=0)
    assert "target_kind" not in frame_row(shot, "front", truth, score, ["m"])
    import pandas as pd

    rows = [frame_row(shot, "front", truth, score, ["m"], "person"),
            frame_row(SimpleNamespace(**{**vars(shot), "target": "car"}), "front", truth,
                      SimpleNamespace(per_model=[0.4], composite=0.4, detected=False, false_positives=0), ["m"],
                      "vehicle")]
    summary = summarise(pd.DataFrame(rows), 0.5, "front")
    assert summary["kind.person"] == pytest.approx(0.8) and summary["kind.vehicle"] == pytest.approx(0.4)
    assert not any(k.startswith("kind.") for k in summarise(pd.DataFrame(rows[:1]).drop(columns="target_kind"),
                                                             0.5, "front"))
