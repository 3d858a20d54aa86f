"""One-shot scenarios (issue 49, item 5): `case.frames=K` keeps K of a trajectory's frames, and a search of one-shot
trials with `search.runs=per_search` (one MLflow run per search, the scenarios' rows on it) reproduces its rows."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compose_cfg

from garage_exp.core.errors import GarageError
from garage_exp.plan import classify, load_plan
from garage_exp.run.preflight import resolve_plan_path
from garage_exp.scenario.assemble import build_scene
from garage_exp.scenario.build import one_shot
from garage_exp.run.spec import scene_spec


@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def shots(library, *overrides: str):
    cfg = compose_cfg(*overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))[1].shots


def test_one_shot_picks_evenly_spaced_frames_ends_included():
    assert one_shot(5, None) == {0, 1, 2, 3, 4}
    assert one_shot(5, 9) == {0, 1, 2, 3, 4}
    assert one_shot(5, 1) == {0}
    assert one_shot(5, 2) == {0, 4}
    assert one_shot(33, 3) == {0, 16, 32}


def test_a_k_frame_scenario_is_k_of_the_trajectorys_own_frames(library):
    """case=1's trajectory (33 frames a colour, the ego driving): frames=3 keeps its first, middle and last frame
    with the same ego and target poses and the same times; frames=1 its first."""
    full = [s for s in shots(library, "case=1") if s.label == "black"]
    three = [s for s in shots(library, "case=1", "case.frames=3") if s.label == "black"]
    assert [s.position for s in three] == [full[k].position for k in (0, 16, 32)] == [20.0, 12.0, 4.0]
    for got, want in zip(three, (full[0], full[16], full[32])):
        assert (got.ego, got.time, got.poses["target_black"]) == (want.ego, want.time, want.poses["target_black"])
    one = shots(library, "case=1", "case.frames=1", "palette.target_colours=[black]")
    assert [(s.position, s.label) for s in one] == [(20.0, "black")]


def test_a_static_case_is_one_shot_already(library):
    """A case without a motion actor is one frame a variant whatever frames says (1 frame: nothing to drop)."""
    assert len(shots(library, "case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]",
                     "case.frames=1")) == 1


@pytest.mark.parametrize("bad", ["0", "-2"])
def test_frames_below_one_is_refused_naming_the_key(library, bad):
    with pytest.raises(GarageError, match=r"case\.frames.*frames must be a whole number >= 1"):
        shots(library, "case=1", f"case.frames={bad}")


def rendered(scene, setup, renderer, cfg) -> np.ndarray:
    from garage_exp.core.plugins import build
    from garage_exp.run.pipeline import FramePipeline, in_view

    sensor = build(cfg.sensor, "a sensor model", "sensor._target_")
    shot = setup.shots[0]
    pipeline = FramePipeline(cfg, scene, renderer, sensor, np.random.default_rng(7))
    return next(iter(pipeline.shots([shot], [scene.cameras[0].name], [in_view(scene, shot.poses)],
                                    [pipeline.sensor_rng]))).rgb


@pytest.mark.render
def test_a_kept_garage_taken_back_renders_what_a_fresh_load_renders(library):
    """renderer.kept_garages=3: plan A, then plan B, then A again with other actors and light: A's SAPIEN scene is
    taken back (not rebuilt) and its frame is pixel-equal to the same scene loaded into a fresh renderer."""
    from conftest import require

    require("vulkan", "vehicles")
    from garage_exp.core.state import STATE
    from garage_exp.render.sapien_backend import get_renderer

    base = ("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=96",
            "camera.height=72", "look=flat")

    def built(*more):
        cfg = compose_cfg(*base, *more)
        classified = classify(load_plan(resolve_plan_path(cfg.plan)))
        return cfg, *build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))

    first, again, other = built("plan=small"), built("plan=small", "case.actors.target.distance=6.5",
                                                    "light.intensity=0.4"), built("plan=obstacles")
    STATE.renderer = None
    renderer = get_renderer()
    renderer.kept_garages = 3
    renderer.load(first[1])
    kept = renderer.sapien_scene
    rendered(first[1], first[2], renderer, first[0])
    renderer.load(other[1])
    assert renderer.sapien_scene is not kept
    renderer.load(again[1])
    assert renderer.sapien_scene is kept  # taken back, not rebuilt
    taken_back = rendered(again[1], again[2], renderer, again[0])
    STATE.renderer = None  # a fresh renderer, as a new process has
    fresh = get_renderer()
    fresh.load(again[1])
    assert np.array_equal(taken_back, rendered(again[1], again[2], fresh, again[0]))
    assert taken_back.std() > 0  # a picture, not a blank
    STATE.renderer = None
    one = get_renderer()  # kept_garages=1 (today): the last garage only, another one is rebuilt
    one.load(first[1])
    was = one.sapien_scene
    one.load(other[1])
    one.load(first[1])
    assert one.sapien_scene is not was


@pytest.mark.render
def test_a_garage_loaded_with_its_kept_textures_renders_what_fresh_textures_render(library):
    """The uploaded textures are kept by material (render/sapien_builder._uploaded): a garage of the real look loaded
    into another renderer's SAPIEN scene takes every one of them from the cache (nothing made or uploaded again), and
    its frame is pixel-equal to the one drawn with every texture made afresh."""
    from conftest import require

    require("vulkan", "vehicles")
    from garage_exp.core.state import STATE
    from garage_exp.render.sapien_backend import get_renderer
    from garage_exp.render.sapien_builder import _uploaded

    cfg = compose_cfg("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=96",
                      "camera.height=72", "plan=small", "materials.wetness=0.6")
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    scene, setup = build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))
    assert any(s.material.texture is not None for e in scene.entities for s in e.shapes if hasattr(s, "material"))
    frames = []
    for fresh_textures in (True, False):
        if fresh_textures:
            _uploaded.cache_clear()
        STATE.renderer = None  # another renderer, another SAPIEN scene
        renderer = get_renderer()
        renderer.kept_garages = 1
        made = _uploaded.cache_info().misses
        renderer.load(scene)
        frames.append(rendered(scene, setup, renderer, cfg))
        if not fresh_textures:
            assert _uploaded.cache_info().misses == made  # every texture taken from the cache
    assert np.array_equal(frames[0], frames[1]) and frames[0].std() > 0


@pytest.mark.render
def test_a_garage_with_another_floor_wetness_and_grime_is_restyled_in_place_as_a_fresh_load_renders_it(library):
    """A wide space draws the floor's wetness and grime and the lines' wear per scenario: the same garage with
    other pictures keeps its SAPIEN scene (its materials given the new pictures, nothing rebuilt), and its frame is
    pixel-equal to the same scene loaded into a fresh renderer."""
    from conftest import require

    require("vulkan", "vehicles")
    from garage_exp.core.state import STATE
    from garage_exp.render.sapien_backend import get_renderer

    base = ("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=96",
            "camera.height=72", "plan=small", "materials=worn")

    def built(*more):
        cfg = compose_cfg(*base, *more)
        classified = classify(load_plan(resolve_plan_path(cfg.plan)))
        return cfg, *build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))

    dry = built("materials.wetness=0.0", "materials.grime=0.2")
    wet = built("materials.wetness=0.9", "materials.grime=0.8", "case.actors.target.distance=6.5")
    STATE.renderer = None
    renderer = get_renderer()
    renderer.load(dry[1])
    loaded = renderer.sapien_scene
    rendered(dry[1], dry[2], renderer, dry[0])
    renderer.load(wet[1])
    assert renderer.sapien_scene is loaded  # restyled in place, not rebuilt
    restyled = rendered(wet[1], wet[2], renderer, wet[0])
    STATE.renderer = None  # a fresh renderer, as a new process has
    fresh = get_renderer()
    fresh.load(wet[1])
    assert np.array_equal(restyled, rendered(wet[1], wet[2], fresh, wet[0]))
    assert restyled.std() > 0


def scene_of(library, *overrides: str) -> tuple:
    """(config, scene, setup) of the overrides."""
    from garage_exp.run.spec import scene_spec

    cfg = compose_cfg(*overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return cfg, *build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))


def fresh_frame(job: tuple) -> np.ndarray:
    """The first frame of a (config, scene, setup) loaded into a fresh renderer, as a new process has it."""
    from garage_exp.core.state import STATE
    from garage_exp.render.sapien_backend import get_renderer

    cfg, scene, setup = job
    STATE.renderer = None
    renderer = get_renderer()
    renderer.load(scene)
    return rendered(scene, setup, renderer, cfg)


@pytest.mark.render
def test_a_garage_with_other_line_wear_and_failed_lamps_rebuilds_only_those_as_a_fresh_load_renders_it(library):
    """A wide space draws the lines' wear and the failed lamps per scenario: worn paint loses pieces
    (scene/markings.py) and another set of failed lamps groups the panels by other materials, so the garage's
    statics change beyond their colours. The same garage with other wear and lamps (and another floor, another
    target distance) keeps its SAPIEN scene: only the bodies of line paint and lamps are rebuilt (the rest
    recoloured, the actors replaced), and its frame is pixel-equal to the same scene loaded into a fresh
    renderer; and back again."""
    from conftest import require

    require("vulkan", "vehicles")
    from garage_exp.core.state import STATE

    base = ("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=96",
            "camera.height=72", "plan=small", "materials=worn", "camera.pitch=8.0")

    def paint(scene):
        return sorted((e.name, len(e.shapes)) for e in scene.entities if e.name.startswith("marking_"))

    def lamps_on(scene):
        return [s.material.emission for e in scene.entities if e.role == "lamp" for s in e.shapes[:1]]

    fresh_lines = scene_of(library, *base, "modifiers.wear.wear=0.0", "materials.wetness=0.0", "light.coverage=1.0")
    worn = scene_of(library, *base, "modifiers.wear.wear=0.8", "materials.wetness=0.7",
                    "case.actors.target.distance=6.5", "light.coverage=0.5", "light.seed=3")
    assert paint(fresh_lines[1]) != paint(worn[1])  # pieces worn away: other geometry, not only other colours
    assert len(set(lamps_on(worn[1]))) == 2 and len(set(lamps_on(fresh_lines[1]))) == 1  # some lamps failed
    fresh_frame(fresh_lines)
    renderer = STATE.renderer
    loaded, before = renderer.sapien_scene, list(renderer._built.merged)
    redrawn = getattr(renderer._built, "redrawn", [])
    renderer._built._boxes = renderer._built.merged_boxes() + 1000.0  # marked: are the kept ones read again?
    renderer.load(worn[1])
    assert renderer.sapien_scene is loaded  # the garage kept loaded, not rebuilt
    after = renderer._built.merged
    assert all((body in after) != (body in redrawn) for body in before)  # only paint and lamps rebuilt
    # The kept bodies' boxes are kept (statics never move), only the new ones' are read from SAPIEN.
    read = np.array([body.get_global_aabb_fast() for body in after], dtype=float).reshape(-1, 2, 3)
    kept = np.array([body in before for body in after])
    boxes = renderer._built.merged_boxes()
    assert kept.any() and (~kept).any()
    assert np.array_equal(boxes[kept] - 1000.0, read[kept]) and np.array_equal(boxes[~kept], read[~kept])
    renderer._built._boxes = read  # unmarked: the frame below culls by them
    renderer._index_bodies(renderer._built, worn[1])
    assert np.array_equal(renderer.bodies.lo[-len(after):], read[:, 0])
    again = rendered(worn[1], worn[2], renderer, worn[0])
    assert np.array_equal(again, fresh_frame(worn)) and again.std() > 0
    renderer = STATE.renderer  # back: fresh paint, every lamp on, on the garage loaded with the worn ones
    renderer.load(fresh_lines[1])
    back = rendered(fresh_lines[1], fresh_lines[2], renderer, fresh_lines[0])
    assert np.array_equal(back, fresh_frame(fresh_lines))


# A one-shot search: one frame a scenario (the lighting case at one distance), the archive's sampler over two
# garages kept loaded, one detector, one MLflow run for the search.
ONESHOT = ["-m", "hydra/sweeper=search", "search.sampler=archive", "search.trials=6", "search.startup=3",
           "search.batch=2", "search.runs=per_search", "renderer.kept_garages=2", "case=light",
           "case.motion.values=[8.0]", "palette.target_colours=[black]", "camera.width=320", "camera.height=240",
           "detector.models=[yolo11n_int8_openvino_model]", "plan=choice(small,obstacles)",
           "light.intensity=interval(0.1,1.0)", "case.actors.target.distance=interval(5.0,10.0)",
           "search.descriptors=[{source:kind,values:[car,adult,child]},{source:distance,edges:[0,7,100]}]"]


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_one_shot_search_keeps_one_run_and_its_elites_rerun_to_their_frame_rows(tmp_path):
    """search.runs=per_search: no MLflow run per trial, the parent holds every scenario's row (scenarios.csv, the
    trials' own frame tables); each archive elite's rerun command (a plain job in a fresh renderer) gives its
    scenario's frame row."""
    import optuna
    import pandas as pd
    from conftest import require, rerun_elite, run_app
    from optuna.trial import TrialState

    from garage_exp.tracking import runs as tracking

    require("vulkan", "vehicles", "models")
    stores = [f"search.storage=sqlite:///{tmp_path / 'optuna.db'}", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"]
    r = run_app([*ONESHOT, *stores], tmp_path)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "6 trials in one MLflow run (search.runs=per_search): 6 finished, 0 failed" in r.stdout
    storage = f"sqlite:///{tmp_path / 'optuna.db'}"
    study = optuna.load_study(study_name=optuna.get_all_study_names(storage)[0], storage=storage)
    done = study.get_trials(states=(TrialState.COMPLETE,))
    assert len(study.trials) == 6 and len(done) >= 4
    assert {t.params["plan"] for t in study.trials} == {"small", "obstacles"}  # both garages, switched between
    assert all(t.user_attrs["run_id"] is None and t.user_attrs["frames"] == 1 for t in done)
    mlc = tracking.client(f"sqlite:///{tmp_path / 'mlflow.db'}")
    exp = mlc.get_experiment_by_name("garage_exp")
    runs = mlc.search_runs([exp.experiment_id])
    assert [run.data.tags.get("sweep") for run in runs] == ["parent"]  # the search's one run
    logged = {a.path for a in mlc.list_artifacts(runs[0].info.run_id, "search")}
    assert "search/scenarios.csv" in logged
    rows = pd.read_csv(tmp_path / "sweep" / "search" / "scenarios.csv")
    assert sorted(rows.trial) == sorted(t.number for t in done)  # one row a one-shot scenario
    for t in done:  # the parent's rows are the trials' own
        own = pd.read_csv(f"{t.user_attrs['output_dir']}/frames.csv")
        pd.testing.assert_frame_equal(rows[rows.trial == t.number].drop(columns="trial").reset_index(drop=True),
                                      own, check_dtype=False)
    elites = pd.read_csv(tmp_path / "sweep" / "search" / "archive.csv")
    assert len(elites) >= 1
    for _, elite in elites.iterrows():  # each elite's rerun command gives its scenario's frame row
        theirs = rows[rows.trial == int(elite.trial)].drop(columns="trial").reset_index(drop=True)
        pd.testing.assert_frame_equal(rerun_elite(elite, tmp_path), theirs, check_dtype=False)


def test_a_one_shot_trials_composition_keeps_hydras_types_and_flags():
    """A one-shot trial's config (composed once per group levels, parsed overrides cached, values set on a copy)
    is Hydra's composition with its schema's types and struct flag, and trials do not share nodes."""
    from types import SimpleNamespace

    from conftest import hydra_loader
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from garage_exp.scenario.schema import CaseConf
    from garage_exp.search.launch import CachedLaunch

    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search"], RunMode.MULTIRUN)
        launch = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, {"light", "case", "plan"})
        trial = ["light=dim", "light.intensity=0.3", "case.frames=1", "search.runs=per_search", "search.trial=0"]
        ours, hydras = launch.take(trial), loader.load_sweep_config(master, trial)
        assert OmegaConf.to_container(ours) == OmegaConf.to_container(hydras)
        assert OmegaConf.is_struct(ours) and OmegaConf.get_type(ours.case) is CaseConf
        with pytest.raises(Exception, match="frames"):
            ours.case.frames = "many"  # the schema's type still checks a value
        other = launch.take(["light=dim", "light.intensity=0.9", "search.trial=1"])
        assert (ours.light.intensity, other.light.intensity, other.case.frames) == (0.3, 0.9, None)


def test_a_one_shot_trials_hydra_node_is_handed_over_as_hydras_copy_would_be():
    """run_lean hands HydraConfig the trial's own `hydra` node (launch.hand_hydra_node) instead of Hydra's copy
    (set_config): HydraConfig then reads what set_config gives, typed HydraConf, read-only, its parent the job's
    config; and the node is the trial's, not a copy."""
    import copy
    from types import SimpleNamespace

    from conftest import hydra_loader
    from hydra.conf import HydraConf
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from garage_exp.search.launch import CachedLaunch, hand_hydra_node

    with hydra_loader() as loader:
        master = loader.load_configuration("config", ["hydra/sweeper=search"], RunMode.MULTIRUN)
        launch = CachedLaunch(SimpleNamespace(config_loader=loader), None, master, {"light", "case", "plan"})
        trial = launch.take(["light=dim", "light.intensity=0.3", "search.runs=per_search", "search.trial=0"])
    twin = copy.deepcopy(trial)
    previous = HydraConfig.instance().cfg
    try:
        HydraConfig.instance().set_config(twin)
        hydras = HydraConfig.instance().cfg
        hand_hydra_node(trial)
        ours = HydraConfig.instance().cfg
        assert OmegaConf.to_container(ours, resolve=False) == OmegaConf.to_container(hydras, resolve=False)
        assert OmegaConf.get_type(ours, "hydra") is HydraConf and OmegaConf.is_readonly(ours.hydra)
        assert ours.hydra._get_parent() is trial and ours.hydra is trial._get_node("hydra")
        assert HydraConfig.get().runtime.choices["light"] == "dim"
    finally:
        HydraConfig.instance().cfg = previous
