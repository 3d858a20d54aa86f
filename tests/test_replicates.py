"""Replicates: seeded nuisance variation per cell, built without rendering."""

from __future__ import annotations

import math

import pytest
import pandas as pd
from conftest import run_app
from test_golden import GOLDEN, compare
from test_scenario import build, library  # noqa: F401  (the module's vehicle-library fixture)

from garage_exp.core.errors import GarageError
from garage_exp.run.preflight import check_config


def shots_of(setup, k):
    return [s for s in setup.shots if s.replicate == k]


def lateral(pose_a, pose_b, heading_deg):
    """How far pose_b stands to the left of pose_a, across a heading."""
    h = math.radians(heading_deg)
    return -(pose_b.x - pose_a.x) * math.sin(h) + (pose_b.y - pose_a.y) * math.cos(h)


def test_replicate_zero_is_the_scenario_as_written(library):
    _, one = build(library, "case=light")
    _, three = build(library, "case=light", "replicates=3")
    def key(shots):  # replicate 0's actors where the scenario put them (the others wait out of the scene)
        return [(s.label, s.position, s.ego, {n: p for n, p in s.poses.items() if "_r" not in n}, s.target)
                for s in shots]

    assert key(one.shots) == key(shots_of(three, 0))
    assert len(three.shots) == 3 * len(one.shots)
    assert [s.index for s in three.shots] == list(range(len(three.shots)))


def test_replicates_vary_within_their_ranges_and_keep_their_names_apart(library):
    scene, setup = build(library, "case=light", "replicates=4")
    base = shots_of(setup, 0)
    models = set()
    for k in (1, 2, 3):
        rep = shots_of(setup, k)
        assert len(rep) == len(base)
        for a, b in zip(base, rep):
            assert b.target == f"{a.target}_r{k}" and b.label == a.label and b.position == a.position
            heading = a.ego.yaw
            assert abs(lateral(a.ego, b.ego, heading)) <= 0.3 + 1e-9  # the ego's lateral position
            ta, tb = a.poses[a.target], b.poses[b.target]
            assert abs((tb.yaw - ta.yaw + 180) % 360 - 180) <= 5.0 + 1e-9
        models |= {scene.entity(s.target).model for s in rep if s.label == "black"}
        assert shots_of(setup, k)[0].ego != base[0].ego  # something did move
    assert len(models) > 1  # the black target's model is drawn from its size class and colour
    names = [e.name for e in scene.entities]
    assert len(names) == len(set(names))
    actors = {e.name for e in scene.actors() if e.role != "ego"}
    for shot in setup.shots:  # each shot places every actor; only its own replicate's stand in the scene
        assert set(shot.poses) == actors
        standing = {n for n, p in shot.poses.items() if p is not None}
        assert standing == {shot.target}


def test_replicate_k_is_the_same_in_every_cell_and_every_run(library):
    _, bright = build(library, "case=light", "replicates=3", "light=bright")
    scene_dim, dim = build(library, "case=light", "replicates=3", "light=dim")
    _, again = build(library, "case=light", "replicates=3", "light=bright")
    assert [(s.ego, s.poses) for s in bright.shots] == [(s.ego, s.poses) for s in dim.shots]
    assert [(s.ego, s.poses) for s in bright.shots] == [(s.ego, s.poses) for s in again.shots]
    _, other_seed = build(library, "case=light", "replicates=3", "seed=7")
    assert shots_of(other_seed, 1)[0].ego != shots_of(bright, 1)[0].ego


def test_a_jitter_that_would_overlap_shrinks_instead_of_failing(library):
    # Case 3's cars stand in neighbouring bays: a 1 m lateral range would put some of them into each other.
    _, setup = build(library, "case=3", "replicates=3", "replicate.offset=1.0")
    assert len(shots_of(setup, 2)) == len(shots_of(setup, 0))


def test_zero_ranges_and_no_model_draws_repeat_replicate_zero(library):
    _, setup = build(library, "case=1", "replicates=2", "replicate.offset=0", "replicate.yaw=0",
                     "replicate.ego_offset=0", "replicate.models=false")
    for a, b in zip(shots_of(setup, 0), shots_of(setup, 1)):
        assert a.ego == b.ego and a.poses[a.target] == b.poses[b.target]


def test_a_bay_offset_moves_the_actor_across_its_bay(library):
    _, plain = build(library, "case=2")
    _, moved = build(library, "case=2", "case.actors.ego.offset=0.25")
    a, b = plain.shots[0].ego, moved.shots[0].ego
    assert math.hypot(b.x - a.x, b.y - a.y) == pytest.approx(0.25)
    assert lateral(a, b, a.yaw) == pytest.approx(0.25)


@pytest.mark.parametrize("override, where", [("replicates=0", "replicates"), ("replicate.yaw=-1", "replicate.yaw")])
def test_bad_replicate_values_name_their_key(override, where):
    from conftest import compose_cfg

    with pytest.raises(GarageError) as err:
        check_config(compose_cfg(override))
    assert err.value.where == where


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_replicated_job_renders_replicate_zero_as_before(tmp_path, mlflow_uri):
    """Replicate 0 of a replicated job is the golden frame table; the other replicates see their own
    target, unoccluded in the lighting case (no replicate's car stands in another's frames)."""
    proc = run_app(["case=light", "light=bright", "look=flat", "case.motion.values=[6.0,12.0]", "replicates=2",
                    "renderer.save_frames=none", f"tracking.uri={mlflow_uri}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = pd.read_csv(tmp_path / "run" / "frames.csv")
    assert list(table.replicate) == [0] * 4 + [1] * 4
    zero = table[table.replicate == 0].drop(columns="replicate").reset_index(drop=True)
    compare(zero, pd.read_csv(GOLDEN / "caselight_bright_ideal.csv"), "replicate 0")
    one = table[table.replicate == 1]
    assert list(one.target) == [f"{t}_r1" for t in zero.target] and list(one.position) == list(zero.position)
    assert (one.visible_fraction > 0.9).all() and (one.composite > 0).any()


def test_a_replicated_jobs_summary_carries_its_interval_over_replicates():
    from garage_exp.results.table import summarise

    rows = [{"camera": "front", "replicate": k, "label": "black", "composite": c, "visible_fraction": 1.0,
             "false_positives": 0} for k, c in enumerate([0.2, 0.4, 0.6, 0.8]) for _ in range(3)]
    out = summarise(pd.DataFrame(rows), 0.5, "front")
    assert out["confidence_mean"] == pytest.approx(0.5) and out["replicates"] == 4
    assert 0.2 <= out["confidence_mean_low"] < 0.5 < out["confidence_mean_high"] <= 0.8
    single = summarise(pd.DataFrame(rows).assign(replicate=0), 0.5, "front")
    assert "confidence_mean_low" not in single
