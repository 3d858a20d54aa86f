"""The garage generator (`plan=generated`, garage_exp/plan/generator.py): valid plans for 1,000 seeds (plan level:
classified, every lane and bay reachable from the entrance, ramps, sizes within the ordinance's ranges), the same seed
the same plan and different seeds different plans, a saved draw that reloads to the same plan and garage, the
shipped cases hosted where their site kinds exist, bad settings in one line, and one job on a generated garage.
The bad settings a user types are corpus entries too (tests/bad_inputs/cases.yaml, `plan-generator-*`)."""

from __future__ import annotations

import dataclasses
import math
import time
from collections import Counter

import numpy as np
import pytest
from conftest import ROOT, compose_cfg, require, run_app, run_module

from garage_exp.core.errors import GarageError
from garage_exp.plan.schema import PlanGeneratorConf
from garage_exp.plan import classify, load_plan
from garage_exp.plan import generator as G
from garage_exp.plan.features import corners, entrance_distance, straight_runs
from garage_exp.plan.model import DRIVEABLE, ENTRANCE, EXIT, LANE, STEPS

FAMILIES = list(G.FAMILIES)
DEFAULTS = dataclasses.asdict(PlanGeneratorConf())
ALL = G.generator_settings({**DEFAULTS, "family": FAMILIES})


def test_conf_level_is_the_schema_s_defaults():
    """conf/plan/generated.yaml spells out the schema's defaults (a user reads the ranges there)."""
    import yaml

    level = yaml.safe_load((ROOT / "conf" / "plan" / "generated.yaml").read_text())
    assert level["generator"] == DEFAULTS and level["file"] is None and level["seed"] == 0


def test_a_thousand_seeds_draw_valid_plans():
    """Every seed of the default ranges over all four families: a plan the loader accepts, every lane reachable
    from the entrance and every bay beside a reachable lane, no bay without a lane, the ramps on the perimeter, every
    size within its range and the ordinance's (lanes wide enough for their bays, end bays clear of their pillars),
    and the features the cases stand at. A draw takes well under 50 ms."""
    kinds, slowest, started = Counter(), 0.0, time.perf_counter()
    for seed in range(1000):
        t = time.perf_counter()
        d = G._draw_cached.__wrapped__(ALL, seed)  # not the memo: each draw made
        slowest = max(slowest, time.perf_counter() - t)
        plan, params = d.plan, dict(d.params)
        classified = classify(plan)
        S = plan.S
        m, n = S.shape
        # reachable: every driveable cell from the entrance; every bay has a reachable lane beside it
        dist = entrance_distance(plan)
        assert np.isfinite(dist[np.isin(S, DRIVEABLE)]).all(), seed
        for cell in classified.all_cells():
            if cell.kind == "parking":
                beside = [(cell.i + STEPS[d][0], cell.j + STEPS[d][1]) for d in cell.lanes]
                assert any(S[c] == LANE and np.isfinite(dist[c]) for c in beside), (seed, cell)
                assert cell.type != "type4", (seed, cell)
        # ramps: one entrance, an exit when two ramps were drawn, on the perimeter, facing a lane
        ramps = np.argwhere(np.isin(S, (ENTRANCE, EXIT)))
        assert (S == ENTRANCE).sum() == 1 and (S == EXIT).sum() == params["ramps"] - 1, seed
        assert all(i in (0, m - 1) or j in (0, n - 1) for i, j in ramps), seed
        # sizes: lanes (rows and columns as wide as the draw's lane), bays, pillars, ceiling
        garage = d.garage
        lane = params["lane_width"]
        assert ALL.lane_width[0] <= lane <= ALL.lane_width[1] + 1e-9 and lane >= G.lane_minimum(garage["bay_width"]) - 1e-9
        assert ALL.bay_depth[0] <= params["bay_depth"] <= ALL.bay_depth[1]
        assert ALL.pillar_size[0] <= garage["pillar_size"] <= ALL.pillar_size[1]
        assert ALL.ceiling_height[0] <= garage["ceiling_height"] <= ALL.ceiling_height[1]
        assert garage["ceiling_height"] - G.BEAM_DEPTH >= G.CLEAR_HEIGHT
        assert garage["bay_width"] >= G.BAY_MIN and ALL.bay_width[0] <= params["bay_width"] <= ALL.bay_width[1]
        assert set(np.round(plan.R, 6)) <= {round(lane, 6), round(params["bay_depth"], 6)}, seed
        k, p = params["bays_per_span"], garage["pillar_size"]
        aisles = [i for i in range(m) if (S[i] == LANE).sum() > n // 2]
        cross = [j for j in range(n) if any(S[i, j] == LANE for i in range(m) if i not in aisles)]
        spans = [j for j in range(n) if S[aisles[0], j] == LANE and j not in cross]
        assert spans and all(plan.C[j] == lane for j in cross) and all(plan.R[i] == lane for i in aisles), seed
        for j in spans:  # every span cell divides into k bays; its end bays keep 2.40 m clear of their pillar:
            # half of it between two spans, all of it where the pillar is pushed off a cross lane into the span
            width = float(plan.C[j])
            shares = [p / 2 if b in spans else p for b in (j - 1, j + 1)]
            assert math.floor(width / garage["bay_width"] + 1e-6) == k, (seed, j)
            if k > 1:
                assert width / k - max(shares) >= G.BAY_ONE_SIDE - 1e-9 and width / k >= G.BAY_MIN, (seed, j)
            else:
                assert width - sum(shares) >= G.BAY_BOTH_SIDES - 1e-9, (seed, j)
        family = d.family
        kinds[family] += 1
        types = Counter(c.type for c in classified.all_cells() if c.kind == "lane")
        if family != "spine":
            assert corners(classified), (seed, family)  # a corner with its pillar: case 1's site
        if family in ("loop", "grid", "spine"):
            assert types["t_junction"], (seed, family)
        kinds["runs"] += bool(straight_runs(classified))
    assert set(kinds) >= set(FAMILIES) and min(kinds[f] for f in FAMILIES) > 150  # each family drawn
    assert kinds["runs"] >= 995  # a straight run with bays (most cases' site): a short loop's two ramps can split it
    assert slowest < 0.05, slowest
    assert time.perf_counter() - started < 30


def test_same_seed_same_plan_different_seeds_differ():
    fresh = G._draw_cached.__wrapped__
    a, b = fresh(ALL, 3), fresh(ALL, 3)
    assert G.draw_yaml(a) == G.draw_yaml(b) and a.params == b.params
    texts = {G.draw_yaml(fresh(ALL, seed)) for seed in range(40)}
    assert len(texts) == 40
    shapes = {fresh(ALL, seed).plan.shape for seed in range(40)}
    assert len(shapes) > 5  # the seeds differ in layout, not only in the sizes


def test_one_family_is_drawn_alone_and_names_its_plans():
    """Held-out evaluation: a family left out of training is drawn on its own (plan.generator.family=spine)."""
    for family in FAMILIES:
        gen = G.generator_settings({**DEFAULTS, "family": family})
        assert {G.draw(gen, seed).family for seed in range(10)} == {family}
        assert G.draw(gen, 0).plan.name == f"generated_{family}_0"
    mixed = Counter(G.draw(ALL, seed).family for seed in range(100))
    assert set(mixed) == set(FAMILIES)


def test_a_saved_draw_reloads_to_the_same_plan(tmp_path):
    """`python -m garage_exp.plan draw --seed 5 -o F` writes a plan file that loads to the same S, R, C and
    garage values, and a job on `plan.file=F` hands the garage on as `plan=generated plan.seed=5` does."""
    from garage_exp.run.preflight import hand_on, resolve_plan_path

    out = tmp_path / "draw5.yaml"
    proc = run_module("garage_exp.plan", ["draw", "--seed", "5", "family=[loop,comb,grid,spine]", "-o", str(out),
                                          "--map", str(tmp_path / "draw5.png")], tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "draw5.png").read_bytes()[:4] == b"\x89PNG"
    drawn = G.draw(ALL, 5).plan
    saved = load_plan(out)
    assert saved.name == drawn.name and saved.garage == drawn.garage and saved.garage
    assert np.array_equal(saved.S, drawn.S) and np.array_equal(saved.R, drawn.R) and np.array_equal(saved.C, drawn.C)
    assert [c.type for c in classify(saved).all_cells()] == [c.type for c in classify(drawn).all_cells()]
    generated = compose_cfg("plan=generated", "plan.seed=5", "plan.generator.family=[loop,comb,grid,spine]")
    from_file = compose_cfg(f"plan.file={out}")
    for cfg in (generated, from_file):
        plan = load_plan(resolve_plan_path(cfg.plan))
        assert np.array_equal(plan.S, drawn.S) and plan.garage == drawn.garage
        hand_on(cfg, plan)
        assert {k: cfg.garage[k] for k, _ in drawn.garage} == dict(drawn.garage)
        assert cfg.modifiers.pillar.size == dict(drawn.garage)["pillar_size"]
    # the shipped plans carry no garage: their jobs keep garage.* as configured
    research = compose_cfg()
    hand_on(research, load_plan(resolve_plan_path(research.plan)))
    assert research.garage == compose_cfg().garage and research.modifiers.pillar.size == 0.6


def test_unset_plan_keys_leave_the_shipped_plans_jobs_as_they_were():
    """plan.seed and plan.generator (None on every shipped plan) are neither logged nor hashed: a job's
    identity (resume) and its MLflow params stay what they were."""
    from garage_exp.core.plain import plain
    from garage_exp.tracking.provenance import config_hash, config_params

    cfg = compose_cfg("plan=small")
    params = config_params(cfg)
    assert "plan.seed" not in params and "plan.generator" not in params and params["plan.name"] == "small"
    container = plain(cfg)
    assert container["plan"].pop("seed") is None and container["plan"].pop("generator") is None
    assert config_hash(cfg) == config_hash(container)
    generated = config_params(compose_cfg("plan=generated", "plan.seed=4"))
    assert generated["plan.seed"] == "4" and generated["plan.generator.family"] == "loop"


@pytest.mark.parametrize("setting, where, said", [
    ({"lane_width": [5.5, 5.5]}, "plan.generator.lane_width", "narrower than the 6.50 m"),
    ({"bay_width": 2.2}, "plan.generator.bay_width", "2.2 m is outside 2.3-3 m"),
    ({"bay_depth": [4.5, 5.0]}, "plan.generator.bay_depth", "4.5 m is outside 5-6 m"),
    ({"ceiling_height": 2.1}, "plan.generator.ceiling_height", "2.0 m clear under 0.25 m beams"),
    ({"family": ["loop", "maze"]}, "plan.generator.family", "unknown layout family 'maze'"),
    ({"aisles": 2.5}, "plan.generator.aisles", "2.5 is not an integer"),
    ({"spans": [7, 4]}, "plan.generator.spans", "runs backwards"),
    ({"cores": [1, 2, 3]}, "plan.generator.cores", "not a value or a range"),
    ({"wall_bays": 1.5}, "plan.generator.wall_bays", "not a probability"),
    ({"lanes": 2}, "plan.generator.lanes", "unknown setting 'lanes' (did you mean 'spans'?)"),
])
def test_a_bad_setting_is_one_line_naming_its_key(setting, where, said):
    with pytest.raises(GarageError) as info:
        G.generator_settings({**DEFAULTS, **setting})
    assert info.value.where == where and said in str(info.value) and "\n" not in str(info.value)


def test_a_bad_settings_file_names_the_file_and_key(tmp_path):
    """`draw --settings FILE`: the one line names the file and the key; exit 2, nothing written."""
    settings = tmp_path / "mine.yaml"
    settings.write_text("family: comb\nlane_width: [4.0, 6.0]\n")
    proc = run_module("garage_exp.plan", ["draw", "--settings", str(settings), "-o", str(tmp_path / "x.yaml")], tmp_path)
    assert proc.returncode == 2 and not (tmp_path / "x.yaml").exists()
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and f"{settings}: plan.generator.lane_width: 4 m is outside" in lines[0], proc.stderr
    settings.write_text("family: comb\naisles: [2, 2]\n")
    proc = run_module("garage_exp.plan", ["draw", "--settings", str(settings), "--seed", "2"], tmp_path)
    assert proc.returncode == 0 and "name: generated_comb_2" in proc.stdout


CASES = sorted(p.stem for p in (ROOT / "conf" / "case").glob("*.yaml"))
RIG = {"slots": ["camera=fisheye4"], "cpra": ["camera=rear"]}  # cases scored by a camera the front rig lacks


def test_generated_garages_host_the_shipped_cases():
    """On a draw of each family (two seeds each), every shipped case whose site kind the plan has is placed by
    the case builder (make_case, as tests/test_cases.py): no site the generator makes is too short, narrow or low
    for the case written for the research's plan. spine has no corner: case 1 is the one it cannot host."""
    import copy

    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.core.plain import settings
    from garage_exp.run.preflight import classified_plan, hand_on, resolve_plan_path
    from garage_exp.run.spec import scene_spec
    from garage_exp.scenario import make_case
    from garage_exp.scenario.sites import find_site

    require("vehicles")
    library = VehicleLibrary()
    hosted, absent = Counter(), Counter()
    for case in CASES:
        base = compose_cfg("plan=generated", f"case={case}", *RIG.get(case, []))
        for family in FAMILIES:
            for seed in (0, 1):
                cfg = copy.deepcopy(base)
                cfg.plan.generator.family, cfg.plan.seed = family, seed
                classified = classified_plan(resolve_plan_path(cfg.plan))
                hand_on(cfg, classified.plan)
                job = scene_spec(settings(cfg))
                try:
                    find_site(job.case.site, classified, job.garage)
                except GarageError:
                    absent[case, family] += 1
                    continue
                setup = make_case(job, classified, library, np.random.default_rng(seed))
                assert setup.shots, (case, family, seed)
                hosted[case] += 1
    assert set(absent) <= {("1", "spine")}, absent
    assert all(hosted[c] >= 6 for c in CASES), hosted


@pytest.mark.render
@pytest.mark.detect
@pytest.mark.slow
def test_a_job_renders_on_a_generated_garage(tmp_path):
    """`python -m garage_exp plan=generated plan.seed=3 ...` at 320 x 240: the job runs, logs the draw's plan
    and garage, and its frames hold the target."""
    import pandas as pd

    require("vulkan", "vehicles", "models")
    proc = run_app(["plan=generated", "plan.seed=3", "case=1", "camera.width=320", "camera.height=240",
                    "palette.target_colours=[black]", "case.motion.step=4", "renderer.save_frames=all",
                    f"tracking.uri=sqlite:///{tmp_path}/mlflow.db"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    frames = pd.read_csv(tmp_path / "run" / "frames.csv")
    assert len(frames) >= 3 and frames["visible_fraction"].max() > 0.2
    assert len(list((tmp_path / "run" / "frames").glob("*_front.png"))) >= len(frames)
    import yaml

    config = yaml.safe_load((tmp_path / "run" / ".hydra" / "config.yaml").read_text())
    drawn = G.draw(G.generator_settings(config["plan"]["generator"]), 3)
    assert config["plan"]["seed"] == 3
    from garage_exp.tracking import runs as tracking
    from mlflow import MlflowClient

    mlc = MlflowClient(tracking.tracking_uri(f"sqlite:///{tmp_path}/mlflow.db"))
    run = mlc.search_runs([mlc.get_experiment_by_name("garage_exp").experiment_id])[0]
    assert run.data.params["plan.name"] == drawn.plan.name
    assert float(run.data.params["garage.pillar_size"]) == drawn.garage["pillar_size"]
    assert float(run.data.params["garage.ceiling_height"]) == drawn.garage["ceiling_height"]
