"""The real look (issue 21): procedural materials, clutter, contact shadows and the real camera.

Description-level tests need no renderer; one module-scoped job renders the lighting case under the real look
to check that ground truth stays exact where clutter hides a target and that a contact shadow never carries
its actor's id."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import compose_cfg, run_app

from garage_exp.perception.sensor import make_sensor
from garage_exp.scene.description import Box, Decal, Material, Texture
from garage_exp.scene.textures import image
from garage_exp.run.spec import scene_spec


def built(*overrides: str):
    from garage_exp.assets.vehicles import VehicleLibrary
    from garage_exp.plan import classify, load_plan
    from garage_exp.run.preflight import resolve_plan_path
    from garage_exp.scenario.assemble import build_scene

    cfg = compose_cfg(*overrides)
    classified = classify(load_plan(resolve_plan_path(cfg.plan)))
    scene, setup = build_scene(scene_spec(cfg), classified, VehicleLibrary(), np.random.default_rng(cfg.seed))
    return cfg, classified, scene, setup


def test_flat_look_is_the_scene_before_the_look():
    """look=flat adds nothing: the description is what the build gave before issue 21 (the golden tables
    then prove the frames did not move)."""
    from garage_exp.scene import look

    calls = []
    original = look.dress
    look.dress = lambda *a, **k: calls.append(1)
    try:
        _, _, bare, _ = built("case=light", "look=flat")
    finally:
        look.dress = original
    _, _, flat, _ = built("case=light", "look=flat")
    assert calls == [1]
    assert [(e.name, e.pose, e.shapes) for e in flat.entities] == [(e.name, e.pose, e.shapes) for e in bare.entities]
    assert flat.lights == bare.lights
    assert all(s.material.texture is None for e in flat.entities for s in e.shapes if isinstance(s, Box))


def test_real_look_dresses_the_structure_adds_clutter_and_shadows():
    cfg, _, scene, _ = built("case=light")
    assert (cfg.look.name, cfg.materials.level, cfg.clutter.level, cfg.sensor.name) == ("real", "worn", "typical",
                                                                                      "camera")
    floors = [s for e in scene.entities if e.name.startswith("floor_") for s in e.shapes]
    assert floors and all(s.material.texture is not None for s in floors)
    kinds = {e.name.split("_")[1] for e in scene.entities if e.name.startswith("clutter_")}
    assert {"duct", "main", "tray", "sprinkler", "arrow", "bay", "wheel", "extinguisher", "level"} <= kinds
    for actor in scene.actors():  # every car and person stands on its own soft shadow
        decals = [s for s in actor.shapes if isinstance(s, Decal)]
        assert len(decals) == 1 and decals[0].material.texture.kind == "shadow", actor.name
    assert any(e.name.startswith("ao_pillar_") for e in scene.entities)
    assert any(e.name.startswith("ao_wall_") for e in scene.entities)
    # the lights hang below their panels (the fixture's reflector), by fixture_drop
    _, _, flat, _ = built("case=light", "look=flat")
    drops = {round(a.position[2] - b.position[2], 6) for a, b in zip(flat.lights, scene.lights)}
    assert drops == {cfg.look.fixture_drop}


def test_nothing_low_stands_in_a_lane():
    """Clutter over a lane hangs above 2.2 m; on a lane's floor only paint (decals) and, at an entrance, the
    bollards at its two sides: a case's path stays clear."""
    _, classified, scene, _ = built("case=1", "clutter=dense")
    plan = classified.plan
    for e in scene.entities:
        if not e.name.startswith("clutter_"):
            continue
        for s in e.shapes:
            cell = plan.cell_at(e.pose.x, e.pose.y)
            if isinstance(s, Box) and cell is not None and plan.is_driveable(*cell):
                if "bollard" in e.name:
                    x0, y0, x1, y1 = plan.cell_rect(*cell)
                    assert min(e.pose.x - x0, x1 - e.pose.x, e.pose.y - y0, y1 - e.pose.y) < 0.3, e.name
                else:
                    assert s.offset.z - s.size[2] / 2 >= 2.2, e.name


def test_materials_levels_differ_and_are_seeded():
    from garage_exp.scene.look import dress_of

    assert dress_of("clean", 0).grime < dress_of("worn", 0).grime
    assert dress_of("wet", 0).wetness > 0 == dress_of("worn", 0).wetness
    assert dress_of("random", 3) == dress_of("random", 3) != dress_of("random", 4)
    base = Material("bay_floor", (0.22, 0.21, 0.19, 1.0), 0.85)
    one = image(Material(base.name, base.color, 0.85, texture=Texture("concrete", 1, 4.0, (("grime", 1.0),))))[0]
    same = image(Material(base.name, base.color, 0.85, texture=Texture("concrete", 1, 4.0, (("grime", 1.0),))))[0]
    other = image(Material(base.name, base.color, 0.85, texture=Texture("concrete", 2, 4.0, (("grime", 1.0),))))[0]
    assert np.array_equal(one, same) and not np.array_equal(one, other)


def test_a_tiled_texture_has_no_seam():
    """Floors are many boxes mapped by world position: a texture's last column continues into its first."""
    rgba, _ = image(Material("f", (0.2, 0.2, 0.2, 1.0), texture=Texture("concrete", 5, 4.0, (("grime", 0.0),))))
    lum = rgba[..., :3].mean(axis=2)
    seam = np.abs(lum[:, 0] - lum[:, -1]).mean()
    inner = np.abs(lum[:, 100] - lum[:, 101]).mean()
    far = np.abs(lum[:, 0] - lum[:, lum.shape[1] // 2]).mean()
    assert seam < 2 * inner < far


def test_wet_floors_shine_where_puddles_are():
    wet = Material("f", (0.2, 0.2, 0.2, 1.0), 0.8, texture=Texture("concrete", 1, 4.0, (("grime", 0.0),
                                                                                      ("wetness", 1.0))))
    _, rough = image(wet)
    assert rough.min() < 0.15 < 0.3 < rough.max()  # puddles gloss, the damp film between them less


def test_a_floors_and_lines_kept_layers_draw_the_pixels_drawn_without_them():
    """A wide space draws grime, wetness and wear per scenario: a floor's noise, stains, cracks and puddles and the
    line paint's noise are drawn once per kind, seed, size (and stain counts) and weighed per picture
    (textures._start, _grime), as a wall's paint and dirt are (_wall_layers). Each picture equals the one drawn
    straight from its random numbers, as the pictures were drawn before they were kept: cold, and warm after
    pictures that share its layers."""
    from garage_exp.scene import textures
    from garage_exp.scene.textures import _blobs, _cracks, _rgba, _rng, fbm

    def floor_drawn(colour, roughness, seed, size, grime, wet):
        rng = _rng("concrete", seed)
        shade = 1.0 + 0.18 * fbm(size, rng) + 0.05 * fbm(size, rng, octaves=3, base=32)
        rough = np.full((size, size), roughness, np.float32)
        if grime > 0:
            stains = _blobs(size, rng, int(3 + 7 * grime), (0.03, 0.09))
            smears = _blobs(size, rng, int(4 + 10 * grime), (0.015, 0.03), stretch=7.0)
            shade *= 1.0 - 0.6 * grime * stains - 0.35 * grime * smears
            shade *= 1.0 - 0.5 * _cracks(size, rng, int(1 + 3 * grime))
            rough -= 0.35 * stains * grime
        if wet > 0:
            rough *= 1.0 - 0.5 * wet
            puddles = np.clip((fbm(size, rng, octaves=4, base=2) + 0.15) * 4.0, 0.0, 1.0) * wet
            shade *= 1.0 - 0.3 * puddles
            rough = rough * (1.0 - puddles) + 0.1 * puddles
        return _rgba(np.asarray(colour), shade), np.clip(rough, 0.03, 1.0)

    def paint_drawn(colour, seed, size, wear):
        rng = _rng("paint", seed)
        gone = np.clip((fbm(size, rng, octaves=5, base=8) + 1.2 * wear - 0.85) * 5.0, 0.0, 1.0)[..., None]
        rgb = np.asarray(colour[:3], np.float32)[None, None] * (1 - gone) + np.float32(0.1) * gone
        rgb *= (1.0 + 0.08 * fbm(size, rng, octaves=3, base=32))[..., None]
        return np.concatenate([np.clip(rgb, 0, 1), np.ones((size, size, 1))], axis=2).astype(np.float32)

    colour = (0.3, 0.29, 0.27, 1.0)
    textures._grime.cache_clear()
    # 0.37 and 0.38 share the stain counts (5, 7, 2): the second is weighed from the first's kept layers
    for grime, wet in ((0.37, 0.0), (0.38, 0.9), (0.0, 0.6), (1.0, 1.0), (0.0, 0.0), (0.12, 0.3)):
        floor = Material("f", colour, 0.8, texture=Texture("concrete", 11, 2.0, (("grime", grime), ("wetness", wet))))
        rgba, rough = textures.image(floor)
        want_rgba, want_rough = floor_drawn(colour, 0.8, 11, 192, grime, wet)
        assert np.array_equal(rgba, want_rgba) and np.array_equal(rough, want_rough), (grime, wet)
    assert textures._grime.cache_info().hits >= 1
    for wear in (0.3, 0.31, 0.9):
        paint = Material("p", (0.9, 0.8, 0.1, 1.0), texture=Texture("paint", 4, 1.0, (("wear", wear),)))
        assert np.array_equal(textures.image(paint)[0], paint_drawn((0.9, 0.8, 0.1, 1.0), 4, 96, wear)), wear

    def wall_drawn(colour, seed, size, tile, grime, tint):
        rng = _rng("wall", seed)
        noise, streaks = fbm(size, rng), fbm(size, rng, octaves=3, base=16)
        shade = (1.0 + tint) * (1.0 + 0.06 * noise)
        z = (np.arange(size, dtype=np.float32) / size * tile)[:, None]
        streaks = np.repeat(np.clip(streaks, 0, 1).mean(axis=0, keepdims=True), size, axis=0)
        shade *= 1.0 - grime * (0.25 * streaks * np.clip((z - 1.0) / 1.8, 0, 1) + 0.3 * np.exp(-z / 0.35))
        return _rgba(np.asarray(colour), np.clip(shade, 0.2, 1.3))

    textures._wall_layers.cache_clear()
    for grime, tint in ((0.37, 0.0), (0.9, 0.0), (0.0, -0.1), (1.0, 0.1)):  # the first two share the layers
        wall = Material("w", colour, texture=Texture("wall", 6, 3.0, (("grime", grime), ("tint", tint))))
        assert np.array_equal(textures.image(wall)[0], wall_drawn(colour, 6, 288, 3.0, grime, tint)), (grime, tint)
    assert textures._wall_layers.cache_info().hits >= 1


def test_a_pictures_srgb_bytes_are_the_formulas():
    """textures.srgb8 converts the whole RGBA picture in place; its bytes are those of the sRGB formula computed as two
    branches joined by np.where, on made pictures of odd sizes, out-of-range and tiny values, float32 and float64,
    and on each kind of texture; `_rgba` writes the picture it computed as a joined float64 copy did."""
    from garage_exp.scene import textures

    def formula(rgba):
        rgb = np.clip(rgba[..., :3], 0, 1)
        srgb = np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
        return np.rint(np.concatenate([srgb, np.clip(rgba[..., 3:4], 0, 1)], axis=2) * 255).astype(np.uint8)

    rng = np.random.default_rng(7)
    made = [rng.random((97, 193, 4), dtype=np.float32) * 1.4 - 0.2, rng.random((64, 64, 4)) ** 6,
            (rng.random((33, 5, 4), dtype=np.float32) * 0.006)]
    for kind in textures.KINDS:
        made.append(textures.image(Material("m", (0.4, 0.3, 0.2, 1.0), texture=Texture(
            kind, 3, 2.5, (("grime", 0.6), ("wetness", 0.4), ("wear", 0.5)))))[0])
    for picture in made:
        ours, want = textures.srgb8(picture), formula(picture)
        assert ours.shape == want.shape and ours.dtype == np.uint8 and ours.tobytes() == want.tobytes()
    shade = (rng.random((40, 30)) * 1.6 - 0.3).astype(np.float32)
    colour = np.asarray((0.3, 0.29, 0.27, 1.0))
    joined = np.concatenate([np.clip(colour[None, None, :3] * shade[..., None], 0.0, 1.0),
                             np.ones((40, 30, 1), np.float32)], axis=2).astype(np.float32)
    assert textures._rgba(colour, shade).tobytes() == joined.tobytes()


def test_only_the_pictures_that_read_the_grime_are_made_again_for_another():
    """A wide space draws the grime per scenario: floors, walls and hazard stripes read it and are made again;
    ceilings, beams and line paint do not read it, keep their materials (so their uploaded pictures) and show
    the pixels a picture drawn with the grime in its parameters showed."""
    from dataclasses import replace

    from garage_exp.scene import look, materials as mat

    clean, dirty = look.Dress(0.1, 0.3, 0.2, 5), look.Dress(0.9, 0.3, 0.2, 5)
    flat = [mat.CEILING, mat.BEAM, mat.BAY_FLOOR, mat.ASPHALT, mat.WALL_PAINT, mat.PILLAR_BAND]
    for m in flat:
        a, b = look.material_map(clean)[m.name](m), look.material_map(dirty)[m.name](m)
        assert (a == b) == (a.texture.kind == "ceiling"), m.name
    lines = [look._paint(mat.LANE_WHITE, clean), look._paint(mat.LANE_WHITE, dirty)]
    assert lines[0] == lines[1]
    for m in (look.material_map(dirty)[mat.CEILING.name](mat.CEILING), lines[1]):
        grimed = replace(m, texture=replace(m.texture, params=tuple(sorted((*m.texture.params, ("grime", 0.9))))))
        assert np.array_equal(image(m)[0], image(grimed)[0])


def test_camera_sensor_noise_vignetting_and_tone():
    params = {"full_well": 10000.0, "exposure": 1.0, "read_noise": 0.0, "target_brightness": 0.18,
              "max_gain": 1.0, "blur_sigma": 0.0, "vignetting": 0.0, "tone": "srgb", "quantize": False}
    grey = np.full((200, 200, 3), 60, np.uint8)  # linear 0.045: 450 e- at exposure 1, 10,000 e- full well
    out = make_sensor(name="t", kind="camera", params=params).apply(grey, np.random.default_rng(0))
    from garage_exp.perception.sensor import srgb_to_linear

    electrons = srgb_to_linear(out.astype(np.float64)) * 10000.0
    assert abs(electrons.mean() - 450.0) < 5 and abs(electrons.std() / np.sqrt(450.0) - 1.0) < 0.05
    vignetted = make_sensor(name="t", kind="camera", params={**params, "vignetting": 0.35, "full_well": 1e7,
                                                             "exposure": 1.0}).apply(grey, np.random.default_rng(0))
    assert vignetted[0, 0].mean() < 0.9 * vignetted[100, 100].mean()
    white = np.full((8, 8, 3), 255, np.uint8)
    hot = {**params, "full_well": 1e7, "exposure": 1.0, "max_gain": 1.0, "target_brightness": 1.0, "quantize": True}
    assert make_sensor(name="t", kind="camera", params=hot).apply(white, np.random.default_rng(0)).max() == 255
    filmic = make_sensor(name="t", kind="camera", params={**hot, "tone": "filmic"})
    assert filmic.apply(white, np.random.default_rng(0)).max() < 255  # highlights roll off


# ---- rendered: ground truth with clutter, shadows without ids ------------------------------------------------

@pytest.fixture(scope="module")
def light_job():
    """The lighting case under the real look, loaded into the process's renderer."""
    from garage_exp.render.sapien_backend import get_renderer

    cfg, classified, scene, setup = built("case=light", "case.motion.values=[8.0]")
    renderer = get_renderer(max_lights=cfg.renderer.max_lights)
    return cfg, scene, setup, renderer


def render_truth(scene, setup, renderer, shot=0):
    from garage_exp.perception.groundtruth import ground_truth
    from garage_exp.scenario.assemble import HIDDEN

    renderer.load(scene)
    s = setup.shots[shot]
    renderer.set_pose("ego", s.ego)
    for name, pose in s.poses.items():
        renderer.set_pose(name, pose if pose is not None else HIDDEN)
    frame = renderer.render(scene.cameras[0].name)
    silhouettes = renderer.unoccluded_ids(scene.cameras[0].name, [s.target])
    return frame, ground_truth(frame, silhouettes, scene, renderer.ids)[0], silhouettes[s.target]


@pytest.mark.render
def test_clutter_that_hides_part_of_a_target_counts_as_an_occluder(light_job):
    """A bollard (clutter, merged static structure) put between the camera and the target: the target's
    visible fraction is exactly its pixels left in the id picture over its unoccluded silhouette."""
    from dataclasses import replace

    from garage_exp.scene.clutter import BOLLARD, _box

    cfg, scene, setup, renderer = light_job
    _, clear, _ = render_truth(scene, setup, renderer)
    assert clear.visible_fraction > 0.99
    shot = setup.shots[0]
    ego, target = shot.ego, shot.poses[shot.target]
    # 2 m ahead of the ego on the line to the target's centre, 1.6 m tall: it cuts the car's middle
    t = 2.5 / np.hypot(target.x - ego.x, target.y - ego.y)
    x, y = ego.x + t * (target.x - ego.x), ego.y + t * (target.y - ego.y)
    hidden = replace(scene, entities=[*scene.entities, _box("clutter_bollard_test", x, y, (0.3, 0.3, 1.6), BOLLARD,
                                                                0.8)])
    frame, truth, silhouette = render_truth(hidden, setup, renderer)
    seen = (frame.ids == renderer.ids[shot.target]) & silhouette
    assert 0.2 < truth.visible_fraction < 0.95
    assert truth.visible_pixels == int(seen.sum()) and truth.unoccluded_pixels == int(silhouette.sum())
    assert truth.unoccluded_pixels == clear.unoccluded_pixels  # the silhouette ignores the bollard
    assert truth.visible_fraction == pytest.approx(seen.sum() / silhouette.sum())


@pytest.mark.render
def test_a_contact_shadow_carries_no_id_of_its_actor(light_job):
    """The shadow decal darkens the floor around the car but its pixels are never the car's: the silhouette and
    the visible pixels are those of the same scene without contact shadows."""
    from dataclasses import replace

    cfg, scene, setup, renderer = light_job
    frame, truth, _ = render_truth(scene, setup, renderer)
    bare = replace(scene, entities=[replace(e, shapes=[s for s in e.shapes if not isinstance(s, Decal)])
                                    for e in scene.entities])
    frame_bare, truth_bare, _ = render_truth(bare, setup, renderer)
    assert truth.unoccluded_pixels == truth_bare.unoccluded_pixels
    assert truth.visible_pixels == truth_bare.visible_pixels
    # ... and it is there: the floor just below the car is darker with it
    x1, y1, x2, y2 = truth.full_box
    below = (slice(y2 + 1, min(y2 + 8, frame.height)), slice(x1, x2))
    assert frame.rgb[below].mean() < 0.85 * frame_bare.rgb[below].mean()


@pytest.mark.render
@pytest.mark.detect
def test_the_default_job_runs_the_real_look_and_exports_its_textures(tmp_path):
    """The CLI's default is look=real: the job logs the camera sensor, and scene.glb holds the textures and
    the blended decals."""
    import json
    import struct

    proc = run_app(["case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]",
                    "renderer.save_frames=none", f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = next(p for p in (tmp_path / "run").parent.rglob("scene.glb"))
    data = run.read_bytes()
    length = struct.unpack("<I", data[12:16])[0]
    gltf = json.loads(data[20:20 + length])
    assert len(gltf.get("images", [])) >= 5
    assert any(m.get("alphaMode") == "BLEND" for m in gltf["materials"])
    assert "sensor=camera" in proc.stdout + proc.stderr


def test_each_replicate_draws_its_own_materials_and_comes_back():
    """Replicate k's surfaces are drawn from seed + k (materials=random: another garage); going from the loaded
    replicate to another and back is the identity, so the renderer's pictures follow the shots' order."""
    from garage_exp.run.pipeline import replicate_materials
    from garage_exp.run.spec import FrameConf

    cfg, _, scene, _ = built("case=light", "materials=random")
    conf = FrameConf.of_config(cfg)
    forward = replicate_materials(conf, scene, 1, 0)
    assert forward and all(old.texture.seed + 1 == new.texture.seed for old, new in forward.items())
    assert any(dict(old.texture.params) != dict(new.texture.params) for old, new in forward.items())
    back = replicate_materials(conf, scene, 0, 1)
    assert {new: back[new] for new in forward.values()} == {new: old for old, new in forward.items()}
    assert replicate_materials(FrameConf.of_config(compose_cfg("case=light", "look=flat")), scene, 1, 0) == {}


def test_the_wear_factor_wears_the_textured_paint_too():
    def paint_wear(*overrides):
        _, _, scene, _ = built("case=light", *overrides)
        return {dict(s.material.texture.params)["wear"] for e in scene.by_role("marking") for s in e.shapes
                if isinstance(s, Box) and s.material.texture is not None}

    fresh, worn = paint_wear("wear=fresh"), paint_wear("wear=worn")
    assert len(fresh) == len(worn) == 1 and min(worn) > min(fresh) + 0.3


@pytest.mark.render
def test_a_job_after_a_restyled_one_renders_the_same_frames():
    """Replicates swap the loaded materials' pictures; the next job loading the same scene must not inherit the
    last replicate's: two runs of a two-replicate job in one process give the same frames."""
    from garage_exp.core.plugins import build
    from garage_exp.render.sapien_backend import get_renderer
    from garage_exp.run.pipeline import render_frames

    cfg, _, scene, setup = built("case=light", "case.motion.values=[8.0]", "palette.target_colours=[black]",
                                 "replicates=2", "materials=random")
    renderer = get_renderer(max_lights=cfg.renderer.max_lights)
    runs = []
    for _ in range(2):
        renderer.load(scene)
        sensor = build(cfg.sensor, "a sensor model", "sensor._target_")
        runs.append([f.rgb for f in render_frames(cfg, scene, setup.shots, renderer, sensor, np.random.default_rng(1))])
    assert len(runs[0]) == 2 and [s.replicate for s in setup.shots] == [0, 1]
    assert all(np.array_equal(a, b) for a, b in zip(*runs))
    assert not np.array_equal(runs[0][0], runs[0][1])  # the replicates differ (materials, target's model)


def test_one_scenes_textures_are_drawn_once():
    """The renderer's load and the job's glTF export both ask for every texture (`textures.image`, `image8`): the
    process's cache keeps a whole scene's (the research plan's ~96, most of them bay-number signs), so a second pass
    draws none again (a cache of 48 was emptied in turn and drew all 96 again at each pass)."""
    from garage_exp.scene import textures
    from garage_exp.scene.description import Decal

    _, _, scene, _ = built("case=1", "palette.target_colours=[black]")
    textured = {s.material for e in scene.entities for s in e.shapes
                if isinstance(s, (Box, Decal)) and s.material.texture is not None}
    assert len(textured) > 48
    for material in textured:
        textures.image8(material)
    before = textures.image.cache_info().misses, textures.image8.cache_info().misses
    for material in textured:
        textures.image8(material)
        textures.image(material)
    assert (textures.image.cache_info().misses, textures.image8.cache_info().misses) == before
