"""A space's requirements (garage_exp/search/require.py): what a camera could see of the target, estimated from the
scene description (perception/sightlines.py), and the search redrawing a draw that cannot meet them, never
rendering it."""

import math

import pytest
from conftest import compose_cfg, hydra_loader, recording_launch
from optuna.trial import TrialState

from garage_exp.core.errors import GarageError
from garage_exp.perception.sightlines import Boxes, entity_boxes, sight, static_boxes
from garage_exp.scene.lenses import lens_of
from garage_exp.scene.description import Box, CameraSpec, Entity, Material, Pose, Scene
from garage_exp.search import require as require_mod
from garage_exp.search import space as space_mod
from garage_exp.search import study as study_mod
from garage_exp.search.loop import SearchLoop
from garage_exp.search.sweep import acceptance

GREY = Material("grey")
CAR = (4.5, 1.8, 1.5)
CAMERA = CameraSpec("front", Pose(0.0, 0.0, 1.5), fovy=60.0, width=640, height=480)


def car(name: str, x: float, y: float = 0.0, yaw: float = 0.0) -> Entity:
    return Entity(name, "target", Pose(x, y, 0.0, yaw), extent=CAR, kind="vehicle")


def wall(name: str, x: float, y0: float, y1: float, height: float = 3.0) -> Entity:
    """A thin wall across the view at x, from y0 to y1."""
    return Entity(name, "structure", Pose(x, (y0 + y1) / 2, 0.0),
                  [Box((0.2, y1 - y0, height), GREY, Pose(0.0, 0.0, height / 2))])


def seen(target: Entity, *blocks: Entity, camera: CameraSpec = CAMERA, ego: Pose = Pose()):
    return sight(static_boxes(Scene("s", entities=list(blocks))), {target.name: (target, target.pose)}, target.name,
                 ego, camera)


def test_a_car_in_the_open_is_all_visible_at_its_distance_and_projected_height():
    s = seen(car("t", 12.0))
    assert s.visible == pytest.approx(1.0)
    # centre of the box: (12, 0, 0.75) from the camera at (0, 0, 1.5)
    assert s.distance == pytest.approx(math.hypot(12.0, 0.75), abs=1e-6)
    fy = lens_of(CAMERA).fy
    near_face = 12.0 - CAR[0] / 2  # the box's top and bottom edges nearest the camera span its projection
    assert s.box_height == pytest.approx(fy * 1.5 / near_face, rel=1e-3)


def test_a_wall_across_the_view_hides_all_of_it_and_half_a_wall_about_half():
    assert seen(car("t", 12.0), wall("w", 6.0, -5.0, 5.0)).visible == 0.0
    half = seen(car("t", 12.0), wall("w", 6.0, 0.0, 5.0)).visible  # covers the car's left half (y > 0)
    assert 0.35 < half < 0.65
    low = seen(car("t", 12.0), wall("w", 9.0, -5.0, 5.0, height=0.8)).visible  # a low wall hides its lowest part
    assert 0.5 < low < 1.0


def test_a_wall_behind_the_target_or_beside_the_sightline_hides_nothing():
    assert seen(car("t", 12.0), wall("behind", 16.0, -5.0, 5.0)).visible == pytest.approx(1.0)
    assert seen(car("t", 12.0), wall("beside", 6.0, 3.0, 8.0)).visible == pytest.approx(1.0)


def test_another_actor_hides_the_target_at_its_own_pose_in_the_shot():
    target, other = car("t", 14.0), car("o", 7.0)
    static = static_boxes(Scene("s"))
    hidden = sight(static, {"t": (target, target.pose), "o": (other, other.pose)}, "t", Pose(), CAMERA)
    moved = sight(static, {"t": (target, target.pose), "o": (other, Pose(7.0, 6.0))}, "t", Pose(), CAMERA)
    gone = sight(static, {"t": (target, target.pose), "o": (other, None)}, "t", Pose(), CAMERA)
    assert hidden.visible < 0.3 and moved.visible == pytest.approx(1.0) and gone.visible == pytest.approx(1.0)


def test_a_target_behind_the_camera_or_outside_the_image_is_not_seen():
    behind = seen(car("t", -10.0))
    assert behind.visible == 0.0 and behind.box_height == 0.0
    aside = seen(car("t", 2.0, 30.0))  # 86 degrees to the left of a 60-degree camera
    assert aside.visible == 0.0
    turned = seen(car("t", -10.0), ego=Pose(0.0, 0.0, 0.0, 180.0))  # the ego turned round faces it
    assert turned.visible == pytest.approx(1.0)


def test_a_car_cut_by_the_image_border_is_truncated_as_ground_truth_says():
    """A car 4 m ahead and 2.5 m to the left sticks out of a 60-degree camera's left border; ahead, nothing does."""
    assert seen(car("t", 12.0)).truncation == 0.0
    cut = seen(car("t", 4.5, 2.5))
    assert 0.2 < cut.truncation < 0.9 and cut.visible == pytest.approx(1.0)


def test_a_shipped_space_settles_its_requirements_and_cells_unless_the_command_sets_them():
    from omegaconf import OmegaConf

    from garage_exp.search.schema import wide_descriptors

    cfg = compose_cfg("space=wide")
    space_mod.settle(cfg, ["space=wide"])
    assert cfg.search.require.min_visible == 0.3 and cfg.search.require.max_truncation == 0.5
    assert [d.source for d in cfg.search.descriptors] == [d.source for d in wide_descriptors()]
    mine = compose_cfg("space=wide", "search.require.min_visible=0.6")
    space_mod.settle(mine, ["space=wide", "search.require.min_visible=0.6"])
    assert mine.search.require.min_visible == 0.6 and mine.search.require.min_box == 25
    plain = compose_cfg()
    space_mod.settle(plain, [])
    assert plain.search.require.min_visible is None and plain.search.archive.emitter == "gaussian"
    assert OmegaConf.to_container(plain.search.descriptors)[0]["source"] == "kind"


def test_the_wide_space_names_its_archive_emitter_and_the_command_or_the_measured_loop_keeps_its_own():
    """conf/space/wide.yaml's `emitter: surrogate` (what beat random there, docs/search.md) is the search's unless
    the command names one; the wide loop's Q arm names the Gaussian step it was measured with (docs/loop.md)."""
    from test_loop_wide import shipped

    cfg = compose_cfg("space=wide")
    space_mod.settle(cfg, ["space=wide"])
    assert cfg.search.archive.emitter == "surrogate"
    q = shipped("loop_wide").arms.Q
    assert q.sampler == "archive" and list(q.overrides) == ["search.archive.emitter=gaussian"]
    measured = compose_cfg("space=wide", *q.overrides)
    space_mod.settle(measured, ["space=wide", *q.overrides])
    assert measured.search.archive.emitter == "gaussian"


def test_a_lens_camera_is_left_to_the_render():
    fisheye = CameraSpec("fish", Pose(0.0, 0.0, 1.0), model="fisheye", fov=190.0)
    assert seen(car("t", 8.0), camera=fisheye) is None


def test_a_rotated_box_hides_where_it_stands():
    """A wall turned 90 degrees (its length along x) beside the sightline hides nothing; across it, all."""
    along = Entity("w", "structure", Pose(6.0, 0.0, 0.0, 90.0), [Box((10.0, 0.2, 3.0), GREY, Pose(0, 0, 1.5))])
    assert seen(car("t", 12.0), along).visible == 0.0  # 10 m long turned to lie along y: across the view
    assert len(Boxes.of(entity_boxes(along))) == 1


def test_the_rule_names_what_a_draw_misses():
    rule = require_mod.Require(min_visible=0.5, min_box=25, max_distance=30.0)
    from garage_exp.perception.sightlines import Sight

    assert rule.unmet(Sight(10.0, 40.0, 0.9)) == []
    assert rule.unmet(Sight(40.0, 10.0, 0.2)) == ["visible 0.20 < 0.5", "box 10 px < 25", "distance 40.0 m > 30"]
    assert require_mod.Require(max_truncation=0.5).unmet(Sight(4.0, 200.0, 1.0, 0.6)) == ["truncation 0.60 > 0.5"]
    assert require_mod.Require.of(compose_cfg().search.require) is None  # no bound set: no requirement


@pytest.mark.parametrize("key, value, message", [
    ("min_visible", 1.5, "outside 0-1"), ("min_box", -1, "negative"), ("max_distance", 0, "positive"),
    ("max_truncation", 1.2, "outside 0-1"),
    ("max_draws", 0, "at least 1")])
def test_a_bad_requirement_is_one_line_naming_its_key(key, value, message):
    cfg = compose_cfg(f"search.require.{key}={value}")
    with pytest.raises(GarageError, match=message) as err:
        study_mod.check_search(cfg.search)
    assert err.value.where == f"search.require.{key}"


def test_the_estimate_on_a_shipped_case_follows_the_pillar():
    """Case 1 on the research plan: the corner's pillar hides part of the car beyond the bend while the ego is
    far, none of it once the ego is close (ground truth measured the same, docs/search.md); the estimate agrees
    with the rendered visible fraction to within 0.08 on average there."""
    from garage_exp.run.preflight import preflight

    p = preflight(compose_cfg("case=1", "look=flat", "palette.target_colours=[black]"), check_space=False, load=False)
    movers = {v.name: v for v in p.setup.vehicles}
    static = static_boxes(p.scene, skip=tuple(movers))
    camera = next(c for c in p.scene.cameras if c.name == p.spec.primary)
    by_position = {}
    for shot in p.setup.shots:
        actors = {n: (v, shot.poses.get(n)) for n, v in movers.items() if v.role != "ego"}
        by_position[shot.position] = sight(static, actors, shot.target, shot.ego, camera)
    assert 0.3 < by_position[20.0].visible < 0.8  # rendered: 0.54
    assert by_position[6.0].visible == pytest.approx(1.0)  # rendered: 1.0
    assert by_position[20.0].box_height == pytest.approx(16.7 * 2, abs=3)  # rendered at 320x240: 16 px


# The loop: a stand-in job that records what was launched (tests/test_search.py's pattern).
# One shot (the ego 6 m before the corner): the target 6.2 to 11.4 m from the camera as it moves 3 to 10 m on.
SPACE = ["plan=tiny", "case.motion.values=[6.0]", "case.actors.target.distance=interval(3.0,10.0)"]


def stubbed_search(tmp_path, name: str, budget: int, max_distance: float) -> tuple:
    """A random search of `budget` trials on SPACE whose jobs are stand-ins that record what was launched:
    (the study, the launched overrides, the trial numbers the loop ran)."""
    from hydra.types import RunMode

    launched = []
    launch = recording_launch(launched, frames=2.0)

    store = f"search.storage=sqlite:///{tmp_path / 'optuna.db'}"
    with hydra_loader() as loader:
        master = loader.load_configuration(
            "config", ["hydra/sweeper=search", "plan=tiny", "search.sampler=random",
                       f"search.require.max_distance={max_distance}", "palette.target_colours=[black]", store],
            RunMode.MULTIRUN)
        space = space_mod.build(SPACE, master, {"plan": ["tiny"]})
        study = study_mod.open_study(master.search, name, 0, space.params)
        ran = SearchLoop(master.search, space, study, launch, budget,
                         compose=lambda overrides: loader.load_sweep_config(master, overrides)).run()
    return study, launched, ran


def test_a_draw_the_requirements_reject_is_redrawn_and_never_launched(tmp_path, capsys):
    """With the target required within 10 m of the camera, every far draw is told PRUNED with its reason and
    redrawn: the study holds its budget of accepted trials, each launched, and no rejected one was launched."""
    study, launched, _ = stubbed_search(tmp_path, "req", 6, max_distance=9)
    trials = study.get_trials()
    rejected = [t for t in trials if "rejected" in t.user_attrs]
    accepted = [t for t in trials if "rejected" not in t.user_attrs]
    assert len(accepted) == 6 and all(t.state == TrialState.COMPLETE for t in accepted)
    assert rejected and all(t.state == TrialState.PRUNED and "distance" in t.user_attrs["rejected"] for t in rejected)
    launched_distances = [float(dict(o.split("=", 1) for o in job)["case.actors.target.distance"]) for job in launched]
    assert len(launched) == 6
    assert {round(t.params["case.actors.target.distance"], 6) for t in accepted} == \
        {round(d, 6) for d in launched_distances}
    assert all(t.user_attrs["require_estimate"]["distance"] <= 9 for t in accepted)
    assert all(t.user_attrs["require_estimate"]["distance"] > 9 for t in rejected)
    assert acceptance(study) == (6, len(trials))
    assert "rejected by the space's requirements" in capsys.readouterr().out


def test_a_space_its_requirements_always_reject_stops_with_one_line(tmp_path):
    from hydra.types import RunMode

    store = f"search.storage=sqlite:///{tmp_path / 'optuna.db'}"
    with hydra_loader() as loader:
        master = loader.load_configuration(
            "config", ["hydra/sweeper=search", "plan=tiny", "search.sampler=random", "search.require.max_distance=1",
                       "search.require.max_draws=3", "palette.target_colours=[black]", store], RunMode.MULTIRUN)
        space = space_mod.build(SPACE, master, {"plan": ["tiny"]})
        study = study_mod.open_study(master.search, "never", 0, space.params)
        loop = SearchLoop(master.search, space, study, lambda batch, idx: pytest.fail("launched"), 4,
                          compose=lambda overrides: loader.load_sweep_config(master, overrides))
        with pytest.raises(GarageError, match="rejected 3 draws in a row") as err:
            loop.run()
    assert err.value.where == "search.require"


def test_an_accepted_draw_hands_its_checked_scene_to_its_job_which_builds_none(tmp_path, monkeypatch):
    """The requirement check builds each draw's scene description once; the job of an accepted draw takes that very
    scene from its preflight instead of building it again: one build a draw, whether accepted or rejected."""
    from types import SimpleNamespace

    from hydra.types import RunMode

    from garage_exp.run.preflight import preflight
    from garage_exp.scenario import assemble

    builds, handed = [], []
    real = assemble.build_scene

    def counted(job, *args, **kwargs):
        builds.append(job)
        return real(job, *args, **kwargs)

    monkeypatch.setattr(assemble, "build_scene", counted)
    store = f"search.storage=sqlite:///{tmp_path / 'optuna.db'}"
    with hydra_loader() as loader:
        master = loader.load_configuration(
            "config", ["hydra/sweeper=search", "plan=tiny", "search.sampler=random", "search.require.max_distance=9",
                       "palette.target_colours=[black]", store], RunMode.MULTIRUN)
        compose = lambda overrides: loader.load_sweep_config(master, overrides)  # noqa: E731

        def launch(batch, idx):  # each accepted draw's job, as far as its preflight (where its scene is built)
            out = []
            for overrides in batch:
                before = len(builds)
                prepared = preflight(compose(overrides), check_space=False, load=False)
                handed.append((len(builds) - before, prepared.scene))
                out.append(SimpleNamespace(return_value={"fair_frames": 2.0, "fair_difficulty": 0.5,
                                                         "fair_confidence": 0.5, "fair_recall": 1.0, "frames": 2.0,
                                                         "visible_fraction_mean": 0.9, "run_id": "r",
                                                         "output_dir": "/nowhere"}))
            return out

        space = space_mod.build(SPACE, master, {"plan": ["tiny"]})
        study = study_mod.open_study(master.search, "handed", 0, space.params)
        SearchLoop(master.search, space, study, launch, 4, compose=compose).run()
    trials = study.get_trials()
    assert len(handed) == 4 and any("rejected" in t.user_attrs for t in trials)
    assert [n for n, _ in handed] == [0, 0, 0, 0]  # no job built its scene: each took the checked one
    assert len(builds) == len(trials)  # one build a draw: the check's
    assert all(scene is not None and scene.entities for _, scene in handed)


def test_a_job_inside_its_own_hydra_runtime_takes_the_scene_its_draw_was_checked_on(monkeypatch):
    """The check runs in the sweep's Hydra runtime, the trial's job in its own: their scene settings differ in where
    the config came from (`config_dirs`, `choices`, read only to name a file in an error) and in nothing the build
    reads. The job takes the checked scene; a refusal is handed on only to the very same settings (its words may
    name a file); settings that differ otherwise are built afresh."""
    from dataclasses import replace

    from garage_exp.core.errors import Infeasible
    from garage_exp.run import preflight as pf
    from garage_exp.run.spec import scene_spec
    from garage_exp.scenario import assemble

    builds = []

    def build(job, *args, **kwargs):
        builds.append(job)
        if job.seed == 5:
            raise Infeasible("the target stands in the occluder", "case.actors.target.distance")
        return f"scene of seed {job.seed}", None

    monkeypatch.setattr(assemble, "build_scene", build)
    monkeypatch.setattr(pf, "_library", lambda: None)
    plan = object()
    checked = scene_spec(compose_cfg("plan=tiny"))
    trial = replace(checked, config_dirs=("/conf",), choices={"plan": "tiny", "case": "1"})  # the job's runtime
    assert trial != checked
    built = pf.scene_of(checked, plan, hand=True)
    assert pf.scene_of(trial, plan) is built and len(builds) == 1  # taken, not built again
    pf.scene_of(checked, plan, hand=True)
    pf.scene_of(replace(trial, seed=checked.seed + 1), plan)  # other settings: built
    assert len(builds) == 3
    refused = replace(checked, seed=5)
    with pytest.raises(Infeasible):
        pf.scene_of(refused, plan, hand=True)
    with pytest.raises(Infeasible):
        pf.scene_of(replace(refused, choices={"case": "other"}), plan)  # another file may be named: refused afresh
    assert len(builds) == 5


def test_a_checked_draw_whose_actors_collide_is_refused_by_its_job_without_a_second_build(monkeypatch):
    """The check's refusal (Infeasible: two actors in one another) is handed on as a scene is: the job's preflight
    of the same settings raises it again, in the same words, and builds nothing; other settings are built."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.run import preflight as pf
    from garage_exp.scenario import assemble

    builds = []

    def refuse(job, *args, **kwargs):
        builds.append(job)
        raise Infeasible("the target stands in the occluder", "case.actors.target.distance")

    monkeypatch.setattr(assemble, "build_scene", refuse)
    monkeypatch.setattr(pf, "_library", lambda: None)
    from types import SimpleNamespace as Job

    plan, job, other = object(), Job(seed=1, case="a"), Job(seed=2, case="a")
    with pytest.raises(Infeasible):
        pf.scene_of(job, plan, hand=True)
    with pytest.raises(Infeasible, match="stands in the occluder"):
        pf.scene_of(Job(seed=1, case="a"), plan)  # equal settings, another object (the job's own)
    assert len(builds) == 1
    with pytest.raises(Infeasible):
        pf.scene_of(other, plan)  # nothing handed on for these settings: built (and refused) afresh
    assert len(builds) == 2


def test_a_draw_whose_actors_collide_is_told_infeasible_in_the_check_and_never_launched(tmp_path, monkeypatch, capsys):
    """A draw the check's scene build refuses (Infeasible: two actors in one another) is told PRUNED infeasible
    there, with the words its job would have returned, and counts in the budget; only the other draws are
    launched (before, each colliding draw was launched as a job that refused it again)."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.scenario import assemble

    real = assemble.build_scene

    def collide_far(job, *args, **kwargs):  # a stand-in collision: every draw beyond 6 m
        if float(job.case.actors["target"].distance) > 6.0:
            raise Infeasible("the target stands in the occluder", "case.actors.target.distance")
        return real(job, *args, **kwargs)

    monkeypatch.setattr(assemble, "build_scene", collide_far)
    study, launched, ran = stubbed_search(tmp_path, "collide", 8, max_distance=30)
    trials = study.get_trials()
    colliding = [t for t in trials if t.params["case.actors.target.distance"] > 6.0]
    assert len(trials) == 8 and colliding and len(colliding) < 8  # both kinds drawn, every draw counted
    assert all(t.state == TrialState.PRUNED and t.user_attrs["infeasible"] and t.user_attrs["frames"] == 0
               and "stands in the occluder" in t.user_attrs["placement"] for t in colliding)
    assert len(launched) == 8 - len(colliding)  # only the others were launched
    assert all(float(dict(o.split("=", 1) for o in job)["case.actors.target.distance"]) <= 6.0 for job in launched)
    assert sorted(ran) == [t.number for t in trials]
    assert "stands in the occluder: infeasible" in capsys.readouterr().out


def test_each_draw_writes_its_attributes_in_one_transaction_before_its_tell(tmp_path, monkeypatch):
    """A draw's own attributes (overrides, worker) go with the check's (its estimate, why it was rejected) or with
    its outcome (infeasible) in one write: a rejected or colliding draw writes once before it is told, an
    accepted one once at its check and once with its outcome. Every trial holds its overrides and worker."""
    from garage_exp.core.errors import Infeasible
    from garage_exp.scenario import assemble
    from garage_exp.search import writes

    real, real_write = assemble.build_scene, writes.write_attrs
    written: list[int] = []

    def collide_near(job, *args, **kwargs):  # a stand-in collision: every draw nearer than 5 m
        if float(job.case.actors["target"].distance) < 5.0:
            raise Infeasible("the target stands in the occluder", "case.actors.target.distance")
        return real(job, *args, **kwargs)

    def counted(store, trial_id, attrs):
        written.append(trial_id)
        real_write(store, trial_id, attrs)

    monkeypatch.setattr(assemble, "build_scene", collide_near)
    monkeypatch.setattr(writes, "write_attrs", counted)
    study, launched, _ = stubbed_search(tmp_path, "once", 8, max_distance=9)
    trials = study.get_trials()
    kinds = {"rejected": [t for t in trials if "rejected" in t.user_attrs],
             "infeasible": [t for t in trials if t.user_attrs.get("infeasible")],
             "accepted": [t for t in trials if t.state == TrialState.COMPLETE]}
    assert all(kinds.values()) and sum(map(len, kinds.values())) == len(trials)  # each kind drawn
    for kind, writes_each in (("rejected", 1), ("infeasible", 1), ("accepted", 2)):
        assert all(written.count(t._trial_id) == writes_each for t in kinds[kind]), kind
    assert all(t.user_attrs["overrides"][-1] == f"search.trial={t.number}" and t.user_attrs["worker"]
               for t in trials)
    assert len(launched) == len(kinds["accepted"])


# Draws of the one-shot case on the small plan, each meant to meet or miss the wide space's requirements one way
# (the occluder, an actor of the case, set aside but where the draw is about it).
ASIDE = ["case.actors.occluder.offset=2.5", "case.actors.occluder.length=0.3"]
FIRST_LOOK_DRAWS = {
    "near and clear": ["case.actors.target.distance=8.0", *ASIDE],
    "far and small": ["case.actors.target.distance=28.0", "camera.fovy=90.0", *ASIDE],
    "cut by the edge": ["case.actors.target.distance=5.0", "case.actors.target.offset=2.0", "camera.fovy=30.0",
                        "case.actors.ego.yaw=8.0", *ASIDE],
    "behind the occluder": ["case.actors.target.distance=12.0", "case.actors.occluder.gap=0.6",
                            "case.actors.occluder.offset=0.0", "case.actors.occluder.length=1.0",
                            "case.actors.target.offset=0.0", "case.actors.target.type=child"],
}
WIDE_RULE = require_mod.Require(min_visible=0.3, min_box=25, max_distance=30.0, max_truncation=0.5)


def test_the_first_look_rejects_what_the_built_scene_rejects_with_the_same_estimate():
    """`first_look` judges the case's placed actors before their garage exists: a draw it rejects, the built
    scene's judge rejects too, with the same box, distance and truncation and a visible fraction no lower (the
    garage can only hide more); a draw the judge accepts, it leaves to the judge."""
    from garage_exp.run.preflight import preflight
    from garage_exp.scenario.assemble import cameras

    decided, judged = {}, {}
    for name, draw in FIRST_LOOK_DRAWS.items():
        p = preflight(compose_cfg("case=oneshot", "plan=small", "camera.width=320", "camera.height=240", *draw),
                      check_space=False, load=False)
        full = require_mod.judge(WIDE_RULE, p.scene, p.setup, p.spec.primary)
        first = require_mod.first_look(WIDE_RULE, p.setup, cameras(p.spec.scene, p.setup), p.spec.primary)
        judged[name], decided[name] = full, first
        if first is not None:
            assert not full.ok, name
            assert (first.best.box_height, first.best.distance, first.best.truncation) == \
                (full.best.box_height, full.best.distance, full.best.truncation), name
            assert first.best.visible >= full.best.visible, name
    assert judged["near and clear"].ok and decided["near and clear"] is None
    assert decided["far and small"].why.startswith("box") and "truncation" in decided["cut by the edge"].why
    assert "visible 0.00" in decided["behind the occluder"].why  # the occluder is one of the case's actors


def test_the_first_look_leaves_a_target_only_the_garage_hides_to_the_judge():
    """A wall of the built garage across the view: the judge rejects the draw (nothing visible), the first look,
    which sees no garage, cannot and does not."""
    from types import SimpleNamespace

    target = car("target", 12.0)
    ego = Entity("ego", "ego", Pose(), extent=CAR, kind="vehicle")
    setup = SimpleNamespace(vehicles=[target, ego], shots=[SimpleNamespace(
        target="target", poses={"target": target.pose, "ego": Pose()}, ego=Pose())])
    scene = Scene("s", entities=[wall("w", 6.0, -5.0, 5.0), target, ego], cameras=[CAMERA])
    full = require_mod.judge(WIDE_RULE, scene, setup, "front")
    assert not full.ok and full.why.startswith("visible 0.00")
    assert require_mod.first_look(WIDE_RULE, setup, [CAMERA], "front") is None
    assert require_mod.judge(WIDE_RULE, Scene("s", entities=[target, ego], cameras=[CAMERA]), setup,
                             "front").ok  # without the wall, accepted


def test_a_draw_the_first_look_rejects_builds_no_garage_and_is_told_as_the_judge_would(tmp_path, monkeypatch):
    """In the search, a draw whose actors alone miss the requirements is rejected before its garage is built:
    told PRUNED with `rejected`, never launched, and no garage built for it."""
    from garage_exp.scene import structure

    garages = []
    real = structure.build_garage
    monkeypatch.setattr(structure, "build_garage", lambda *a, **k: garages.append(1) or real(*a, **k))
    study, launched, _ = stubbed_search(tmp_path, "first", 4, max_distance=9)
    trials = study.get_trials()
    rejected = [t for t in trials if "rejected" in t.user_attrs]
    assert rejected and all("distance" in t.user_attrs["rejected"] for t in rejected)
    assert len(launched) == 4
    infeasible = [t for t in trials if t.user_attrs.get("infeasible")]  # refused before any garage, as ever
    assert len(garages) == len(trials) - len(rejected) - len(infeasible)  # only the accepted draws' garages
