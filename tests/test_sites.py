"""Every site, not the nearest (issue 49, item 2; garage_exp/scenario/sites.py): each kind of site lists all the
plan's sites of its kind, site 0 is the one the research's cases always stood at, `case.site_index` and
`case.site_draw` pick another, and a site that does not host a case passes it to the next in order."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import numpy as np
import pytest
from conftest import compose_cfg, require, run_app

from garage_exp.core.errors import GarageError
from garage_exp.core.paths import PLANS_DIR
from garage_exp.plan import features
from garage_exp.plan.classify import Classified
from garage_exp.run.preflight import classified_plan
from garage_exp.scenario import sites
from garage_exp.scenario.build import check_case
from garage_exp.run.spec import scene_spec

PLANS = sorted(p.stem for p in PLANS_DIR.glob("*.yaml"))
KINDS = ("corner", "bay_beside_pillar", "straight_run", "t_junction", "lane_bays")
# The default sites of every shipped plan, written by the code before issue 49 (381e3fc: one site per kind, the
# one nearest the entrance or the longest straight lane): tests/sites/default_sites.json.
PINNED = json.loads((Path(__file__).parent / "sites" / "default_sites.json").read_text())
# Sites of each kind, counted on the shipped plans when every site became a site (2026-12-05).
COUNTS = {"research": {"corner": 2, "bay_beside_pillar": 44, "straight_run": 4, "t_junction": 2, "lane_bays": 6},
          "realistic": {"corner": 3, "bay_beside_pillar": 44, "straight_run": 3, "t_junction": 2, "lane_bays": 6},
          "garage26x30": {"corner": 2, "bay_beside_pillar": 504, "straight_run": 36, "t_junction": 22,
                          "lane_bays": 38}}


@pytest.fixture(scope="module")
def garage():
    return compose_cfg().garage


def plan(name: str) -> Classified:
    return classified_plan(PLANS_DIR / f"{name}.yaml")


def fingerprint(s: sites.Site) -> str:
    """A site's geometry as text (the form tests/sites/default_sites.json pins)."""
    return repr((s.name, sorted((n, (p.origin, p.axis, p.heading, round(p.lo, 9), round(p.hi, 9), p.cell))
                                for n, p in s.paths.items()),
                 [(b.bay.i, b.bay.j, b.bay.index, b.facing) for b in s.bays],
                 {k: [(b.bay.i, b.bay.j, b.bay.index) for b in v] for k, v in s.sides.items()}, s.pillar, s.focus))


@pytest.mark.parametrize("name", PLANS)
def test_site_0_of_every_kind_is_the_one_the_cases_always_stood_at(name, garage):
    """Without an index, and at index 0, every kind's site is the one the code before issue 49 found, on every
    shipped plan (so every golden table holds); a plan without a site of the kind says the same line as then."""
    c = plan(name)
    for kind in KINDS:
        want = PINNED[f"{name}/{kind}"]
        try:
            default = sites.find_site(kind, c, garage)
        except GarageError as exc:
            assert str(exc).split(": ", 1)[1] == want
            continue
        assert fingerprint(default) == want, kind
        assert fingerprint(sites.find_site(kind, c, garage, index=0)) == want
        assert fingerprint(sites.find_site(kind, c, garage, draw=0.0)) == want
        assert getattr(sites, kind)(c, garage).index == 0


@pytest.mark.parametrize("name", sorted(COUNTS))
def test_each_kind_lists_every_site_of_the_plan_nearest_the_entrance_first(name, garage):
    c = plan(name)
    dist = features.entrance_distance(c.plan)
    pillars = {(p.a, p.b) for p in c.pillars}
    for kind, count in COUNTS[name].items():
        if name == "garage26x30":  # (building its 600 sites costs 10 s: counted only)
            assert sites.site_count(kind, c, garage) == count
            continue
        found = sites.every_site(kind, c, garage)
        assert len(found) == sites.site_count(kind, c, garage) == count, kind
        assert [s.index for s in found] == list(range(count))
        assert len({fingerprint(s) for s in found}) == count, f"{kind}: two sites alike"
    if name == "garage26x30":
        return
    # corners: every corner lane cell with a pillar at its inner corner, once, nearest the entrance first
    corners = sites.every_site("corner", c, garage)
    cells = [cell for cell in c.of_type("corner") if features.inner_vertex(cell) in pillars]
    assert sorted(s.cell for s in corners) == sorted((cell.i, cell.j) for cell in cells)
    assert [dist[s.cell] for s in corners] == sorted(dist[s.cell] for s in corners)
    # T-junctions: every one
    tees = sites.every_site("t_junction", c, garage)
    assert sorted(s.cell for s in tees) == sorted((cell.i, cell.j) for cell in c.of_type("t_junction"))
    assert [dist[s.cell] for s in tees] == sorted(dist[s.cell] for s in tees)
    # straight runs: every maximal run of 3+ straight cells with bays beside it, longest first
    runs = sites.every_site("straight_run", c, garage)
    assert [s.cell for s in runs] == [(r.cells[0].i, r.cells[0].j) for r in features.straight_runs(c)]
    cells = [len(r.cells) for r in features.straight_runs(c)]
    assert cells == sorted(cells, reverse=True) and min(cells) >= 3
    # bays beside a pillar: each bay once, its pillar at one of its lane-side corners, nearest the entrance first
    beside = sites.every_site("bay_beside_pillar", c, garage)
    assert len({(s.bays[0].bay.i, s.bays[0].bay.j, s.bays[0].bay.index) for s in beside}) == len(beside)
    lane_dist = [dist[s.paths["lane"].cell] for s in beside]
    assert lane_dist == sorted(lane_dist)
    for s in beside:
        bay, (fx, fy) = s.bays[0].bay, s.bays[0].facing
        px, py = s.focus.x, s.focus.y
        front = (bay.x + fx * bay.depth / 2, bay.y + fy * bay.depth / 2)
        corners_of_front = [(front[0] + k * -fy * bay.width / 2, front[1] + k * fx * bay.width / 2) for k in (-1, 1)]
        assert min(math.hypot(px - x, py - y) for x, y in corners_of_front) <= garage.pillar_size + 1e-9
    # cruising lanes: the straight runs, then every corner's approach
    assert len(sites.every_site("lane_bays", c, garage)) == len(runs) + len(corners)


def test_a_draw_picks_floor_of_draw_times_count_and_an_index_past_the_count_is_refused():
    for count in (1, 2, 3, 7, 44, 504):
        for draw in np.linspace(0.0, 0.999999, 97):
            assert sites.pick(count, draw=float(draw)) == math.floor(draw * count)
        assert sites.pick(count, draw=1.0) == count - 1  # the closed end of a search's interval: the last
        assert sites.pick(count) == 0 and sites.pick(count, index=count - 1) == count - 1
        with pytest.raises(GarageError, match=rf"case.site_index: {count} is past the {count} corner site\(s\) "
                                              rf"of plan p \(0..{count - 1}\)"):
            sites.pick(count, index=count, kind="corner", plan="p")


@pytest.mark.parametrize(("overrides", "message"), [
    (["case.site_index=-1"], "case.site_index: a site's index is >= 0, got -1"),
    (["case.site_draw=1.5"], r"case.site_draw: a draw is in \[0, 1\], got 1.5"),
    (["case.site_draw=-0.1"], r"case.site_draw: a draw is in \[0, 1\], got -0.1"),
    (["case.site_index=1", "case.site_draw=0.5"], "case.site_draw: give site_index or site_draw, not both"),
])
def test_a_bad_pick_is_refused_before_the_plan_is_read(overrides, message):
    with pytest.raises(GarageError, match=message):
        check_case(scene_spec(compose_cfg("case=3", *overrides)))


def test_a_site_of_your_own_has_no_sites_to_pick_among(garage):
    c = plan("research")
    with pytest.raises(GarageError, match="case.site_index: case.site_index and case.site_draw pick among a shipped "
                                          "kind's sites .* my_sites.ramp is a function of your own"):
        sites.find_site({"_target_": "my_sites.ramp"}, c, garage, index=1)


# --- the cases at every site ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def library():
    require("vehicles")
    from garage_exp.assets.vehicles import VehicleLibrary

    return VehicleLibrary()


# case -> (its site kind, the path or bay the ego stands on)
CASES = {"1": ("corner", "approach"), "2": ("bay_beside_pillar", None), "3": ("straight_run", "lane"),
         "pedestrian": ("straight_run", "lane"), "stepout": ("straight_run", "lane")}
# (plan, case) -> {site asked: site that hosts it}: the sites that do not host a case, measured 2026-12-05. The
# pedestrian case's adult does not fit between the two parked cars of the research plan's fourth run; the
# realistic plan's bays are 5.0 m deep, too short for case 2's ego 0.3 m behind the bay line (so its runs of
# such bays pass the case on to the next deep one); garage26x30's runs with no bays on their left pass stepout on.
SKIPPED = {("research", "pedestrian"): {3: 0},
           ("realistic", "2"): {**{k: 6 for k in range(2, 6)}, **{k: 34 for k in range(8, 34)},
                                **{k: 42 for k in range(38, 42)}},
           ("garage26x30", "stepout"): {18: 19, 23: 24, 26: 27, 35: 0}}
STEPS = {"1": 4.0, "2": 5.0, "3": 2.0, "pedestrian": 1.0, "stepout": 4.0}  # fewer frames: the places are the test


def ego_at_site(site: sites.Site, where: str | None, pose) -> bool:
    """The ego stands on the line of the site's path `where` (within 1.5 m of its centre line, at most 10 m past its
    ends: case 3's ego stands 8 m before the close bay, which may lie before the run's first cell), or in the
    site's bay 0."""
    if where is None:
        bay = site.bays[0].bay
        return math.hypot(pose.x - bay.x, pose.y - bay.y) < bay.depth / 2
    path = site.paths[where]
    dx, dy = pose.x - path.origin[0], pose.y - path.origin[1]
    along, across = dx * path.axis[0] + dy * path.axis[1], -dx * path.axis[1] + dy * path.axis[0]
    return abs(across) <= 1.5 and path.lo - 10.0 <= along <= path.hi + 10.0


@pytest.mark.parametrize(("plan_name", "case"), [(p, c) for p in ("research", "realistic") for c in CASES]
                         + [("garage26x30", "1"), ("garage26x30", "stepout")])
def test_every_site_of_a_case_builds_and_stands_the_case_there(plan_name, case, library, garage):
    """make_case at every site of the case's kind: each gives a shot list (a site that does not host the case
    passes it on, SKIPPED), the ego stands at the site that hosts it, and distinct sites put it in distinct
    places."""
    from garage_exp.scenario import make_case

    kind, where = CASES[case]
    c = plan(plan_name)
    cfg = compose_cfg(f"case={case}", f"plan={plan_name}", f"case.motion.step={STEPS[case]}")
    every = sites.every_site(kind, c, garage)
    hosts, starts = {}, {}
    for k in range(len(every)):
        cfg.case.site_index = k
        setup = make_case(scene_spec(cfg), c, library, np.random.default_rng(cfg.seed))
        hosts[k] = setup.site_index
        ego = setup.shots[0].ego
        assert ego_at_site(every[setup.site_index], where, ego), (k, setup.site_index)
        starts[k] = (round(ego.x, 3), round(ego.y, 3), round(ego.yaw, 1))
    assert {k: h for k, h in hosts.items() if h != k} == SKIPPED.get((plan_name, case), {})
    hosted = [k for k in hosts if hosts[k] == k]
    assert len({starts[k] for k in hosted}) == len(hosted), "two sites put the ego in one place"


def test_a_site_passed_on_or_drawn_builds_as_the_site_picked_directly(library):
    """Skipping (research, pedestrian: site 3 -> 0) and drawing (case 3: draw 0.6 of 4 sites -> 2) give the shot
    list and the models that picking that site by its index gives: each try starts from the same random state."""
    from garage_exp.scenario import make_case

    c = plan("research")

    def built(*overrides):
        cfg = compose_cfg(*overrides, "case.motion.step=2.0")
        setup = make_case(scene_spec(cfg), c, library, np.random.default_rng(cfg.seed))
        return setup.site_index, [(s.ego, s.poses) for s in setup.shots], [e.model for e in setup.vehicles]

    assert built("case=pedestrian", "case.site_index=3") == built("case=pedestrian", "case.site_index=0")
    assert built("case=3", "case.site_draw=0.6") == built("case=3", "case.site_index=2")
    assert built("case=3", "case.site_draw=0.6")[1] != built("case=3")[1]
    index, shots, _ = built("case=3", "replicates=2", "case.site_index=3")
    assert index == 3 and ego_at_site(sites.every_site("straight_run", c, compose_cfg().garage)[3], "lane",
                                      shots[-1][0])  # replicate 1 stands at replicate 0's site


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_cases_at_other_sites_render_with_their_target_in_view(tmp_path, mlflow_uri):
    """Case 1 at the research plan's second corner, case 2 at its 30th bay beside a pillar and stepout at its
    third straight run, at 320x240: the target is in view (visible pixels) in some frame of each."""
    import pandas as pd

    require("vulkan", "vehicles", "models")
    jobs = [["case=1", "case.site_index=1", "case.motion.step=4"],
            ["case=2", "case.site_index=30", "case.motion.step=5"],
            ["case=stepout", "case.site_index=2", "case.motion.step=3"]]
    for k, job in enumerate(jobs):
        out = tmp_path / f"job{k}"
        out.mkdir()
        proc = run_app([*job, "camera.width=320", "camera.height=240", "palette.target_colours=[black]",
                        "renderer.save_frames=all", f"tracking.uri={mlflow_uri}"], out)
        assert proc.returncode == 0, proc.stderr[-3000:]
        table = pd.read_csv(out / "run" / "frames.csv")
        assert (table.visible_pixels > 0).any(), job
        assert (table.visible_fraction > 0.5).any(), job


def test_a_kind_of_site_of_your_own_is_one_registered_builder(garage):
    """A kind registered beside its builder lists its sites and is picked like the shipped ones."""
    c = plan("research")

    @sites.register_site("stem_only", sites.t_junction_cells, "no T-junction (the site stem_only needs one)")
    def stem_only(classified, garage, cell):
        return sites.Site("stem_only", {"stem": sites.t_junction_at(classified, garage, cell).paths["stem"]},
                          cell=(cell.i, cell.j))

    try:
        found = sites.every_site("stem_only", c, garage)
        assert [s.cell for s in found] == [s.cell for s in sites.every_site("t_junction", c, garage)]
        assert sites.find_site("stem_only", c, garage, draw=0.99).index == len(found) - 1
        with pytest.raises(GarageError, match="no T-junction"):
            sites.find_site("stem_only", plan("small"), garage)
    finally:
        sites.SITES.pop("stem_only")
    with pytest.raises(GarageError, match="unknown site 'stem_only'"):
        sites.find_site("stem_only", c, garage)


def test_a_site_is_built_once_per_plan_and_each_caller_gets_its_own(garage, monkeypatch):
    """A case passed on from site to site asks for the same sites again at every draw of a search (~15 a draw on
    the wide space): each is built once per plan, kind, bay width, pillar size and index, and handed out as a
    copy equal to a fresh build; another plan object, another index, another pillar size or a kind registered
    anew under the same name is built again."""
    from omegaconf import OmegaConf

    from garage_exp.core.state import STATE

    STATE.clear("process")
    built = []
    kind = sites.SITES["straight_run"]

    def counted(classified, g, feature):
        built.append(feature)
        return kind.build(classified, g, feature)

    monkeypatch.setitem(sites.SITES, "straight_run", sites.SiteKind("straight_run", kind.find, counted, kind.none))
    c = plan("research")
    first = sites.find_site("straight_run", c, garage, index=1)
    again = sites.find_site("straight_run", c, garage, index=1)
    assert len(built) == 1 and again is not first and fingerprint(again) == fingerprint(first)
    sites.find_site("straight_run", c, garage, index=2)
    sites.find_site("straight_run", copy.deepcopy(c), garage, index=1)  # another plan object
    wider = OmegaConf.merge(garage, {"pillar_size": float(garage.pillar_size) + 0.1})
    sites.find_site("straight_run", c, wider, index=1)
    assert len(built) == 4
    assert fingerprint(first) == fingerprint(sites.every_site("straight_run", c, garage)[1]) and again.index == 1
    fresh = sites.SiteKind("straight_run", kind.find, lambda *a: sites.Site("mine", {}), kind.none)
    monkeypatch.setitem(sites.SITES, "straight_run", fresh)
    assert sites.find_site("straight_run", c, garage, index=1).name == "mine"
    for _ in range(sites.BUILT_PLANS + 3):  # a search of new plans keeps the last few plans' sites, no more
        sites.find_site("t_junction", copy.deepcopy(c), garage)
    assert len(sites._BUILT) == sites.BUILT_PLANS


def test_the_gyms_live_scenario_stands_where_the_job_built_the_case(library):
    """The adversary's live scenario (scenario/live.py) finds the site the case set-up used, a skipped one too."""
    from garage_exp.scenario import make_case
    from garage_exp.scenario.live import LiveScenario

    c = plan("research")
    for overrides, site in ((["case=stepout", "case.site_index=2"], 2), (["case=pedestrian", "case.site_index=3"], 0)):
        cfg = compose_cfg(*overrides, "case.motion.step=4.0")
        setup = make_case(scene_spec(cfg), c, library, np.random.default_rng(cfg.seed))
        live = LiveScenario(scene_spec(cfg), c, setup)
        assert setup.site_index == live.site.index == site
        first = setup.shots[0]
        ego, _ = live.poses({"ego": {"distance": first.position}} if cfg.case.motion.actor == "ego" else {})
        assert (round(ego.x, 6), round(ego.y, 6)) == (round(first.ego.x, 6), round(first.ego.y, 6))
