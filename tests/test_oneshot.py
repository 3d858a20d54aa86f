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


@pytest.fixture(scope="module")
def library():
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


def shots(library, *overrides: str):
    cfg = compose_cfg(*overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    return build_scene(cfg, classified, library, np.random.default_rng(cfg.seed))[1].shots


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
