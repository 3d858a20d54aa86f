"""The protocol scenarios (docs/protocols.md) built as a job builds them, without rendering: Euro NCAP's CPNCO
(a child stepping out from beyond two parked cars, timed to meet the ego) and CPRA (the ego reversing toward a
person, scored by its rear camera), and the AVP situations `crossing` and `crouch`; the walk's timing
(garage_exp/scenario/timing.py) and the scoring camera (`case.camera`)."""

from __future__ import annotations

import math

import pytest
from conftest import compose_cfg
from omegaconf import OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.scenario import timing
from garage_exp.scenario.schema import AlongConf

V_CHILD = 5 / 3.6  # the protocols' pedestrian speed, m/s


def prepared(*overrides):
    from garage_exp.run.preflight import check_config, preflight

    cfg = compose_cfg(*overrides)
    check_config(cfg)
    return cfg, preflight(cfg, check_space=False)


def entity(scene, name):
    return next(e for e in scene.entities if e.name == name)


def lateral(pose, ego):
    """How far `pose` stands to the left of the line the ego drives along (its heading through its centre)."""
    h = math.radians(ego.yaw)
    return (pose.x - ego.x) * -math.sin(h) + (pose.y - ego.y) * math.cos(h)


def along(pose, ego):
    h = math.radians(ego.yaw)
    return (pose.x - ego.x) * math.cos(h) + (pose.y - ego.y) * math.sin(h)


# -- the walk ----------------------------------------------------------------------------------------------------

def test_a_walk_reaches_its_speed_after_its_acceleration_distance_and_keeps_it():
    walk = OmegaConf.create({"speed": V_CHILD, "accelerate": 1.0, "start": 0.0, "end": 4.0})
    ramp = 2 * 1.0 / V_CHILD  # s: 1 m at the mean of 0 and v
    assert timing.travelled(walk, ramp) == pytest.approx(1.0)
    assert timing.travelled(walk, ramp / 2) == pytest.approx(0.25)  # constant acceleration: a quarter in half the time
    assert timing.travelled(walk, ramp + 1.0) - timing.travelled(walk, ramp) == pytest.approx(V_CHILD)
    assert timing.travel_time(walk, 4.0) == pytest.approx(ramp + 3.0 / V_CHILD)
    for metres in (0.3, 1.0, 2.5):
        assert timing.travelled(walk, timing.travel_time(walk, metres)) == pytest.approx(metres)
    steady = OmegaConf.create({"speed": 1.4, "accelerate": 0.0})
    assert timing.travelled(steady, 2.0) == pytest.approx(2.8) and timing.travelled(steady, -1.0) == 0.0
    # met at the ego's 2.5 m, reached 10 m before (4 s at 2.5 m/s): it sets off 3.6 s before the ego gets there
    met = AlongConf(speed=V_CHILD, accelerate=1.0, start=-5.0, end=-1.0, meet=2.5)  # as the scene builder has it
    assert timing.start_time(met, lambda x: (12.5 - x) / 2.5) == pytest.approx(4.0 - (ramp + 3.0 / V_CHILD))


def test_at_and_meet_together_are_refused():
    from garage_exp.run.preflight import check_config

    cfg = compose_cfg("case=cpnco", "case.motion.along.child.at=10.0")
    with pytest.raises(GarageError, match=r"cpnco\.yaml.*`at` \(when it sets off\) or `meet`"):
        check_config(cfg)
    with pytest.raises(GarageError, match=r"cpnco\.yaml.*accelerate.*negative"):
        check_config(compose_cfg("case=cpnco", "case.motion.along.child.accelerate=-1"))


# -- Euro NCAP CPNCO -----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("speed", [10.0, 20.0])
def test_cpnco_child_starts_4m_out_beyond_two_parked_cars_and_is_timed_to_meet_the_middle_of_the_ego(speed):
    cfg, job = prepared("case=cpnco", f"ego.speed={speed}")
    scene, shots = job.scene, job.setup.shots
    large, small, child = entity(scene, "car_large"), entity(scene, "car_small"), entity(scene, "child")
    assert 4.3 <= large.extent[0] <= 4.7 and 1.75 <= large.extent[1] <= 1.9  # the protocol's obstruction cars
    assert 4.1 <= small.extent[0] <= 4.4
    assert 1.0 <= child.extent[2] <= 1.2 and child.kind == "person"  # its dummy is about 1.15 m
    first = shots[0]
    ego = first.ego
    cars = {n: first.poses[n] for n in ("car_large", "car_small")}
    # nose to the lane in the left row (the side the ego keeps to), the larger one nearer the ego, about 1 m apart
    assert all(lateral(p, ego) > 3.0 for p in cars.values())
    assert along(cars["car_large"], ego) < along(cars["car_small"], ego) < along(first.poses["child"], ego)
    gap = along(cars["car_small"], ego) - along(cars["car_large"], ego) - (large.extent[1] + small.extent[1]) / 2
    assert 0.9 <= gap <= 1.2
    # the child: 4 m left of the ego's path, its near side 1 m past the smaller car's side
    assert lateral(first.poses["child"], ego) == pytest.approx(4.0)
    beyond = along(first.poses["child"], ego) - child.extent[1] / 2 - (along(cars["car_small"], ego) + small.extent[1] / 2)
    assert beyond == pytest.approx(1.0, abs=0.05)
    # timed as the protocol synchronises it: 4 m in 2 x 1 m / v + 3 m / v, arriving as the ego's front does
    walk = 2 * 1.0 / V_CHILD + 3.0 / V_CHILD
    ego_v = speed / 3.6
    sets_off = 2.55 + ego_v * walk  # the ego's distance when the child starts
    for shot in shots:
        moved = 4.0 - lateral(shot.poses["child"], shot.ego)
        tau = (sets_off - shot.position) / ego_v
        expected = 0.0 if tau <= 0 else (V_CHILD * tau * tau / (2 * 2 / V_CHILD) if tau <= 2 / V_CHILD
                                         else 1.0 + V_CHILD * (tau - 2 / V_CHILD))
        assert moved == pytest.approx(min(expected, 4.0), abs=1e-3), shot.position  # (1.389 m/s in the file)
    last = shots[-1]
    assert last.position == 3.0  # 0.45 m before the meeting: the child is that long short of the ego's centre line
    assert lateral(last.poses["child"], last.ego) == pytest.approx(V_CHILD * 0.45 / ego_v, abs=1e-3)
    assert [s.time for s in shots[:2]] == pytest.approx([0.0, 0.5 / ego_v])


# -- Euro NCAP CPRA ------------------------------------------------------------------------------------------------

def test_cpra_ego_reverses_rear_first_toward_the_person_and_the_rear_camera_faces_it():
    from garage_exp.scene.camera import camera_to_world

    cfg, job = prepared("case=cpra", "camera=rear", "ego.speed=4")
    shots, [rear] = job.setup.shots, job.scene.cameras
    labels = list(dict.fromkeys(s.label for s in shots))
    assert labels == ["adult 25 %", "adult 50 %", "adult 75 %", "child 25 %", "child 50 %", "child 75 %",
                      "adult walking 50 %", "child walking 50 %"]
    ego_width = entity(job.scene, "ego").extent[1]
    for label in labels:
        run = [s for s in shots if s.label == label]
        a, b = run[0].ego, run[1].ego
        heading = (math.cos(math.radians(a.yaw)), math.sin(math.radians(a.yaw)))
        assert (b.x - a.x) * heading[0] + (b.y - a.y) * heading[1] == pytest.approx(-0.5)  # backwards, 0.5 m
        assert [s.time for s in run[:2]] == pytest.approx([0.0, 0.5 / (4 / 3.6)])
        target = run[0].poses[run[0].target]
        cam = camera_to_world(a, rear)
        view = (target.x - cam[0, 3], target.y - cam[1, 3])
        axis = math.atan2(cam[1, 0], cam[0, 0])  # the rear camera's optical axis, seen from above
        off_axis = math.degrees(abs((math.atan2(view[1], view[0]) - axis + math.pi) % (2 * math.pi) - math.pi))
        assert along(target, a) < -9.0 and off_axis < (25.0 if "walking" in label else 5.0)  # before the rear camera
        if "walking" not in label:
            overlap = int(label.split()[1]) / 100
            # 25 % on the ego's left as its driver sees it, 75 % on its right
            assert lateral(target, a) == pytest.approx((0.5 - overlap) * ego_width, abs=0.01)
    walker = [s for s in shots if s.label == "adult walking 50 %"]
    assert lateral(walker[0].poses["adult_walking"], walker[0].ego) == pytest.approx(-4.0)  # 4 m out, on its right
    assert entity(job.scene, "child").extent[2] == pytest.approx(1.15, abs=0.03)


def test_cpra_is_scored_by_the_rear_camera_and_a_rig_without_one_is_refused():
    from garage_exp.run.preflight import check_config
    from garage_exp.scene.camera import scored_camera

    alone = compose_cfg("case=cpra")  # the case brings the rig it is scored by (its defaults list) ...
    check_config(alone)
    assert alone.camera.name == "rear" and scored_camera(alone.camera, "rear") == "rear"
    with pytest.raises(GarageError, match=r"cpra\.yaml: case\.camera: the case is scored by camera 'rear'; "
                                          r"rig front has front"):
        check_config(compose_cfg("case=cpra", "camera=front"))  # ... and the command line's camera still wins
    assert compose_cfg("+experiment=cpra", "camera=fisheye4").camera.name == "fisheye4"
    fisheye4 = compose_cfg("case=cpra", "camera=fisheye4")
    check_config(fisheye4)
    assert fisheye4.camera.cameras[0].name == "front" and scored_camera(fisheye4.camera, "rear") == "rear"
    assert scored_camera(compose_cfg("case=stepout").camera) == "front"  # a case that names none: the first


# -- AVP situations (ISO 23374-1 covers people in the facility's lanes) --------------------------------------------

def test_crossing_walker_crosses_the_egos_path_ahead_of_it():
    cfg, job = prepared("case=crossing")
    shots = job.setup.shots
    sides = [lateral(s.poses["walker"], s.ego) for s in shots]
    assert sides[0] == pytest.approx(4.0) and sides[-1] < 0  # from the far row across the ego's path
    crossing = next(s for s, side in zip(shots, sides) if side <= 0)
    assert 5.0 < crossing.position < 9.0  # it crosses the path about 7 m ahead of the ego at 10 km/h
    assert all(side == pytest.approx(4.0) for s, side in zip(shots, sides) if s.position >= 15.0)


def test_crouch_person_is_a_crouching_adult_beside_the_parked_cars_front_corner():
    cfg, job = prepared("case=crouch")
    person, car = entity(job.scene, "person"), entity(job.scene, "car")
    assert person.model.startswith("adult-male-average-crouching-178cm")
    assert 0.8 < person.extent[2] < 1.1  # about 55 % of 1.78 m
    shot = job.setup.shots[0]
    p, c = shot.poses["person"], shot.poses["car"]
    assert lateral(p, shot.ego) > 3.1  # behind the bay line, in the mouth of the free bay
    assert 0 < along(p, shot.ego) - along(c, shot.ego) < 1.5  # beside the car's side
