"""No bypass of the schema (issue 20, item 4): a key that Hydra's `+` or `++` forces past the struct flag, or a
typo Hydra refuses with its advice to add `+`, is one line naming the override or the file, the key and the
nearest valid key; and a placement its path has no room for is one error naming the actor, the distance, the
path and its length, trimmed only where the actor asks for it (`clip: true`). The command line's side (one line,
exit 2, nothing written) is in the bad-input corpus (tests/bad_inputs/cases.yaml)."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest
from conftest import ROOT, compose_cfg
from hydra.errors import ConfigCompositionException

from garage_exp.config import Config
from garage_exp.core.errors import GarageError, did_you_mean
from garage_exp.core.exits import input_error, unknown_key_line
from garage_exp.core.schema_check import check_schema, override_of, unknown_keys
from garage_exp.scenario.schema import ActorConf, CaseConf
from garage_exp.run.spec import scene_spec



def refused(*overrides: str) -> str:
    cfg = compose_cfg(*overrides, hydra=True)
    with pytest.raises(GarageError) as err:
        check_schema(cfg)
    return str(err.value)


# ------------------------------------------------------------------------------------------ the schema check

@pytest.mark.parametrize("override,line", [
    ("+case.bumper_gapp=1", "+case.bumper_gapp=1: case has no key 'bumper_gapp' (have: name, site, "),
    ("+case.actors.target.offsett=1", "+case.actors.target.offsett=1: case.actors.target has no key 'offsett' "
                                      "(did you mean 'offset'?)"),
    ("+case.motion.stepp=1", "+case.motion.stepp=1: case.motion has no key 'stepp' (did you mean 'step'?)"),
    ("+camera.cameras.0.yaww=5", "+camera.cameras.0.yaww=5: camera.cameras.0 has no key 'yaww' (did you mean "
                                 "'yaw'?)"),
    ("+replicate.offsett=0.1", "+replicate.offsett=0.1: replicate has no key 'offsett' (did you mean 'offset'?)"),
    ("+search.trails=5", "+search.trails=5: search has no key 'trails' (did you mean 'trials'?)"),
    ("+search.suite.per_bands=2", "+search.suite.per_bands=2: search.suite has no key 'per_bands' (did you mean "
                                  "'per_band'?)"),
    ("++light.intensty=2", "++light.intensty=2: light has no key 'intensty' (did you mean 'intensity'?)"),
    ("+sede=1", "+sede=1: the config has no key 'sede' (did you mean 'seed'?)"),
])
def test_a_key_forced_past_the_schema_is_named_with_its_override(override, line):
    assert refused("plan=tiny", override).startswith(line)


def test_nested_dataclasses_inside_dict_and_list_fields_are_checked():
    """An actor of a dict-valued field (the occluder's own, case.actors.<name>), a variant of a list field."""
    assert refused("occluder=pillar_cars", "+occluder.actors.cars_a.nearest=2").startswith(
        "+occluder.actors.cars_a.nearest=2: occluder.actors.cars_a has no key 'nearest' (did you mean "
        "'nearest_bay'?)")
    assert refused("case=pedestrian", "+case.variants.0.lable=x").startswith(
        "+case.variants.0.lable=x: case.variants.0 has no key 'lable' (did you mean 'label'?)")
    found = list(unknown_keys({"case": {"actors": {"a": {"distance": 1.0, "distanse": 2.0}, "b": {"paht": "x"}},
                                        "motion": {"key": "offset"}}}, Config))
    assert found == [(("case", "actors", "a"), "distanse", ActorConf), (("case", "actors", "b"), "paht", ActorConf)]
    assert list(unknown_keys({"case": {"actors": None, "bays": {"anything": "1"}}}, Config)) == []
    assert list(unknown_keys({"bumper_gapp": 1}, CaseConf)) == [((), "bumper_gapp", CaseConf)]


@pytest.mark.parametrize("override", [
    "+modifiers.extra._target_=garage_exp.scene.modifiers.pillar_size",  # dict[str, Any]: the extra factors
    "+modifiers.pillar.anything=1",  # a modifier's keyword arguments are its own to check (when it is called)
    "+sensor.params.gain_map=2.0",  # dict[str, Any]: the sensor model checks its parameters itself
    "+search.suite.bands.low=[0,0.5]",  # dict[str, list[float]]: band names are the user's
    "+palette.target_models.red=hatchback_red",  # dict[str, str]: colour -> model
    "+case.bays.near=1",  # dict[str, str]: the scenario's names for bays
    "+case.variants.0.set.ego.distance=9.0",  # dict[str, Any]: actor.key -> value
])
def test_an_open_dict_stays_open(override):
    cfg = compose_cfg("case=pedestrian", override, hydra=True)
    check_schema(cfg)


# Every shipped level and experiment passes the schema check: test_configs' composition tests (the configs its dry
# runs compose, composed once there).


def test_the_override_that_brought_a_key_and_else_the_file():
    overrides = ["light=dim", "case.actors.target.offset=0.2", "+case.actors.target.offsett=1"]
    assert override_of("case.actors.target.offsett", overrides) == "+case.actors.target.offsett=1"
    assert override_of("case.actors.target.x", ["+case.actors.target={x: 1}"]) == "+case.actors.target={x: 1}"
    assert override_of("case.x", ["+case.x.y=1"]) == "+case.x.y=1"
    assert override_of("case.x", ["~case.x", "case.xy=1"]) is None
    # A key no override names came from a config file: the group's level file is named.
    cfg = compose_cfg("light=dim", "+light.foo=1", hydra=True)
    with pytest.raises(GarageError, match=r"conf/light/dim\.yaml: light has no key 'foo'"):
        check_schema(cfg, overrides=[])


def test_did_you_mean():
    assert did_you_mean("offsett", ["offset", "yaw"]) == " (did you mean 'offset'?)"
    assert did_you_mean("zzz", ["offset", "yaw"]) == " (have: offset, yaw)"


# ------------------------------------------------------------------------ Hydra's error for the un-prefixed typo

def composition_error(*overrides: str) -> ConfigCompositionException:
    with pytest.raises(ConfigCompositionException) as err:
        compose_cfg(*overrides)
    return err.value


def test_an_unprefixed_typo_says_the_key_is_not_in_the_schema():
    """Hydra's message advises `+case.bumper_gapp=1` (which would add a key nothing reads); ours says the key
    does not exist, with the nearest valid one."""
    line = input_error(composition_error("case.actors.target.offsett=1"))
    assert line == "case.actors.target.offsett=1: case.actors.target has no key 'offsett' (did you mean 'offset'?)"
    line = input_error(composition_error("camera.cameras.0.fovyy=90"))
    assert line == "camera.cameras.0.fovyy=90: camera.cameras[0] has no key 'fovyy' (did you mean 'fovy'?)"
    assert "append" not in input_error(composition_error("case.bumper_gapp=1"))


def test_an_unprefixed_key_of_an_open_dict_keeps_hydras_advice():
    """sensor.params is open: there `+sensor.params.read_noise=2` is the right advice, and Hydra's line stays."""
    exc = composition_error("sensor=ideal", "sensor.params.read_noise=2")
    assert unknown_key_line(exc) is None
    assert "+sensor.params.read_noise=2" in input_error(exc)


def test_a_config_files_unknown_key_names_the_file(tmp_path):
    (tmp_path / "light").mkdir()
    (tmp_path / "light" / "night.yaml").write_text("name: night\ncoverage: 0.2\nintensty: 1.0\n")
    line = input_error(composition_error(f"hydra.searchpath=[file://{tmp_path}]", "light=night"))
    assert line == f"{tmp_path}/light/night.yaml: light has no key 'intensty' (did you mean 'intensity'?)"


# ---------------------------------------------------------------------- a placement that does not fit its path

@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def build(library, *overrides: str, config_dir=None):
    from garage_exp.scenario.assemble import build_scene
    from garage_exp.plan import classify, load_plan
    from garage_exp.run.preflight import resolve_plan_path

    extra = [f"hydra.searchpath=[file://{config_dir}]"] if config_dir else []
    cfg = compose_cfg(*extra, *overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(scene_spec(cfg), classified, library, np.random.default_rng(cfg.seed))


SHORT_STEM = ROOT / "tests" / "bad_inputs" / "plans" / "short_stem.yaml"  # a T-junction's 9.2 m stem


def write_stem_case(folder, ego: str) -> None:
    (folder / "case").mkdir(exist_ok=True)
    (folder / "case" / "stem.yaml").write_text(textwrap.dedent(f"""\
        name: stem
        site: t_junction
        actors:
          ego: {{role: ego, model: "${{palette.ego}}", path: stem, {ego}}}
          target: {{role: target, size: medium, colour: red, path: left, distance: 5.0, yaw: 180}}
        """))


def test_a_distance_beyond_the_path_names_the_actor_the_distance_the_path_and_its_length(library, tmp_path):
    write_stem_case(tmp_path, "distance: 16.0")
    with pytest.raises(GarageError) as err:
        build(library, "case=stem", f"plan.file={SHORT_STEM}", config_dir=tmp_path)
    assert str(err.value).split(": ", 1)[1] == (  # the level's file, or outside a Hydra app case=stem
        "case.actors.ego.distance: 16 m does not fit ego's path 'stem' (from cell "
        "(1, 3) towards S, 9.2 m long): ego, 4.8 m long, fits with its centre 2.6 to 6.6 m along it; give a "
        "distance that fits, or case.actors.ego.clip=true to trim it to the path")


def test_clip_true_trims_to_the_room_the_path_leaves(library, tmp_path):
    write_stem_case(tmp_path, "distance: 16.0, clip: true")
    _, setup = build(library, "case=stem", f"plan.file={SHORT_STEM}", config_dir=tmp_path)
    write_stem_case(tmp_path, "distance: 6.6")
    _, fits = build(library, "case=stem", f"plan.file={SHORT_STEM}", config_dir=tmp_path)
    trimmed, asked = setup.shots[0].ego, fits.shots[0].ego
    assert math.hypot(trimmed.x - asked.x, trimmed.y - asked.y) < 0.1  # at the far end of the room, 6.6 m


def test_a_motion_beyond_the_path_is_refused_without_clip(library):
    """Case 2's passing car asks for -15..15 m along a lane that leaves less on one side: it says clip: true
    (its frames are trimmed as they always were); without it the motion's start is refused."""
    with pytest.raises(GarageError, match=r"2\.yaml: case\.motion\.start: -15 m does not fit target's path 'lane' "
                                          r"\(from cell \(\d+, \d+\) towards [NESW], [\d.]+ m long\)"):
        build(library, "case=2", "case.actors.target.clip=false")
    with pytest.raises(GarageError, match=r"case\.motion\.values: 40 m does not fit target's path 'lane'"):
        build(library, "case=2", "case.actors.target.clip=false", "case.motion.values=[0.0,40.0]")
    _, setup = build(library, "case=2")
    assert min(s.position for s in setup.shots) > -15.0  # trimmed, as asked


def test_align_start_must_fit_the_path_too(library):
    with pytest.raises(GarageError, match=r"case\.actors\.ego\.distance: 40 m from its start \(align: start\) "
                                          r"does not fit ego's path 'lane'.*fits with its rear 0\.0 to"):
        build(library, "case=light", "case.actors.ego.distance=40")
