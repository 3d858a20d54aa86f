"""Check a job before anything is written: its config, plan, weights, assets and scene (all but rendering).

Each config group's values are checked by a `check_*` function beside the code that owns the group, called
once, from here: a typo in a sweep's 40th job fails the sweep at once (callbacks.check_sweep), with one line
naming the file or key.
"""

from __future__ import annotations

from dataclasses import dataclass, is_dataclass, replace
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from garage_exp.core.errors import GarageError
from garage_exp.core.plain import settings
from garage_exp.core.paths import PLANS_DIR
from garage_exp.core.state import STATE
from garage_exp.scenario.fits import hint
from garage_exp.scenario.spec import SceneSpec


@dataclass
class PreparedJob:
    """What a job's preflight checked and built; the job runs exactly this (the same config and seed would
    build the same scene again)."""

    plan_path: Path
    classified: Any  # garage_exp.plan.classify.Classified
    scene: Any = None  # garage_exp.scene.description.Scene; None for a dry run
    setup: Any = None  # garage_exp.scenario.CaseSetup; None for a dry run
    bytes_out: int = 0  # estimated bytes the job writes under its output dir
    bytes_store: int = 0  # estimated bytes into a local sqlite store and its artifacts (0 for a server)
    detector: Any = None  # garage_exp.perception.detect.Detector, checked (every entry loaded); None for a dry run
    loaded: bool = False  # the detector's models were loaded (load_models); a job runs only a loaded one
    spec: Any = None  # garage_exp.run.spec.JobSpec: what the stages below the job are told (never the config)
    config: Any = None  # the whole config as plain data (Settings), converted once: what the job logs and hashes
    opened: Any = None  # the detector's warm process (worker.open_detector), opened once by load_models

    def open_detector(self):
        """The detector the job's frames go to: the one load_models opened and checked (opened here if the
        preflight did not load it)."""
        return load_models(self).opened


def resolve_plan_path(plan_cfg) -> Path:
    """`plan.file` (absolute, or relative to where the command was typed) wins over the generator's draw
    (`plan=generated`: `plan.generator` and `plan.seed`, written once to a plan file in the cache), which wins
    over a shipped plan name."""
    if plan_cfg.file:
        import hydra

        return Path(hydra.utils.to_absolute_path(str(plan_cfg.file)))
    generator = plan_cfg.get("generator")
    if generator is not None:
        from garage_exp.plan.generator import draw_file

        return draw_file(settings(generator), plan_cfg.get("seed"))  # a bad setting: one line naming its key
    for suffix in (".yaml", ".yml", ".csv"):
        candidate = PLANS_DIR / f"{plan_cfg.name}{suffix}"
        if candidate.is_file():
            return candidate
    shipped = sorted(p.stem for p in PLANS_DIR.glob("*.*"))
    raise GarageError(f"no shipped plan named {plan_cfg.name!r} (have: {', '.join(shipped)}); "
                      "use plan.file=/path/to/plan.yaml for your own", "plan.name")


def classified_plan(path: Path):
    from garage_exp.plan import classify, load_plan

    try:
        st = path.stat()
        key = (st.st_mtime_ns, st.st_size)
    except OSError:
        key = None
    hit = STATE.plans.get(path)  # a sweep checks many jobs on one plan
    if key is not None and hit is not None and hit[0] == key:
        return hit[1]
    classified = classify(load_plan(path))  # bad plans fail here with the file and the place
    if key is not None:
        STATE.plans[path] = (key, classified)
    return classified


def hand_on(cfg: DictConfig, plan) -> None:
    """A plan that carries the garage it was sized for (a generated plan: its pillar size, bay width, ceiling
    height; plan/generator.py) sets those keys of the job's config, and the `pillar` group's size when that group
    resizes every pillar (conf/pillar/): the bays the plan's cells were sized for are the bays built. The shipped
    plans carry none (nothing changes)."""
    handed = handed_values(cfg, plan)
    if not handed:
        return
    from omegaconf import read_write

    with read_write(cfg):
        for path, value in handed.items():
            OmegaConf.select(cfg, ".".join(path[:-1]))[path[-1]] = value


def handed_values(cfg: DictConfig, plan) -> dict[tuple[str, ...], object]:
    """The keys `hand_on` sets (a path each) and their values, in the order it sets them: the plan's garage keys,
    then the pillar group's size. A search's plain first look sets them on plain data (search/plain_draw.py)."""
    if not plan.garage:
        return {}
    values = dict(plan.garage)
    handed: dict[tuple[str, ...], object] = {("garage", str(key)): value for key, value in values.items()}
    pillar = OmegaConf.select(cfg, "modifiers.pillar")
    if "pillar_size" in values and isinstance(pillar, DictConfig) and "size" in pillar \
            and pillar.get("_target_") == "garage_exp.scene.modifiers.pillar_size":
        handed[("modifiers", "pillar", "size")] = values["pillar_size"]
    return handed


def _library():
    from garage_exp.assets.locate import vehicles_dir
    from garage_exp.assets.vehicles import shared_library

    return shared_library(vehicles_dir())  # missing assets fail in vehicles_dir, saying what to set or run


def check_config(cfg) -> SceneSpec:
    """Every group's values, by its owner's check (the schema already checked the types); no plan or assets
    needed. `cfg`: the composed config, or it as `Settings` (what the checks are handed: plain data). Returns
    the scene builder's settings (run.spec.SceneSpec), converted once here: the scene's groups are checked as
    the builder will be handed them."""
    from garage_exp.perception.detect.detector import check_detector
    from garage_exp.slots.detector import check_slot_detector
    from garage_exp.render.open import check_renderer
    from garage_exp.results.late import check_ego
    from garage_exp.scenario import check_case
    from garage_exp.scenario.build import moves_ego
    from garage_exp.scene.camera import check_camera
    from garage_exp.scene.clutter import check_clutter
    from garage_exp.scene.lamps import check_light
    from garage_exp.scene.look import check_look, check_materials
    from garage_exp.scene.modifiers import check_modifiers
    from garage_exp.scene.parking import check_palette
    from garage_exp.scene.structure import check_garage
    from garage_exp.core.plugins import build
    from garage_exp.openscenario.checks import check_export

    from garage_exp.run.spec import scene_spec

    cfg = settings(cfg)
    for key in ("seed", "light.seed", "palette.seed", "materials.seed"):
        group, _, name = key.rpartition(".")
        value = (cfg.get(group) or {}).get(name) if group else cfg.get(name)
        if value is not None and int(value) < 0:
            raise GarageError(f"{value} is negative (seeds are >= 0)", key)
    job = scene_spec(cfg)
    check_garage(job.garage)
    check_light(job.light)
    check_palette(job.palette)
    check_camera(job.camera, dataset=bool(cfg.dataset))
    check_case(job)
    check_ego(cfg.ego, moving=moves_ego(job.case))
    check_detector(cfg.detector)
    check_slot_detector(cfg.slot_detector)
    check_renderer(cfg.renderer)
    build(cfg.sensor, "a sensor model", "sensor._target_")  # the sensor model checks its own parameters
    check_modifiers(job.modifiers)
    check_look(job.look)
    check_materials(job.materials)
    check_clutter(job.clutter)
    check_slots(job)
    check_export(cfg.export, bool(cfg.dry_run))
    return job


def check_slots(job) -> None:
    """A bird's-eye view (`camera.bev.enabled`, or a case with `slots: true` on a fisheye rig) is stitched from
    raw fisheye pictures over a sane extent. A slot case on a rig without fisheyes runs as an object case
    (slots/frames.py)."""
    from garage_exp.render.bev import check_bev
    from garage_exp.scene.lenses import rig_has

    enabled = bool(job.camera.bev.enabled)
    bev = rig_has(job.camera, "bev")
    if not enabled and not (job.case.slots and bev):
        return
    check_bev(job.camera.bev)
    if not bev:
        raise GarageError(f"a bird's-eye view is stitched from fisheye cameras; rig {job.camera.name} has none "
                          "(camera=fisheye4)", "camera.bev.enabled")
    if job.camera.view != "raw":
        raise GarageError(f"a bird's-eye view is stitched from the raw fisheye pictures, not {job.camera.view} views "
                          "(camera.view=raw)", "camera.view")


def preflight(cfg: DictConfig, check_space: bool = True, load: bool = True, hand: bool = False,
              name=None, screen=None) -> PreparedJob:
    """Check one job's inputs before anything is written; GarageError (one line, naming the file or key)
    on the first problem: the config, the plan, the vehicle assets, and the scene description (garage, case,
    palette, modifiers, cameras) - all but rendering, in ~0.1 s; a real job also that the detector's files exist.
    Then the disk space the job will write, against the free space unless check_space is false (a sweep adds up
    all its jobs' estimates and checks them once). Last, the one check that needs the models (seconds): every
    detector entry loads and answers a probe frame - unless load is false (a sweep loads them after its disk
    check: load_models). Checks that need no model come first, so that their refusal costs no model loading. With
    `hand` (a search's requirement check, which builds no detector: its job's preflight does) the scene built, or
    its refusal, is handed on to the next preflight (scene_of). `name(cfg, plan_name)`: the job's naming of its
    levels (run.job.name_levels), called once the plan is read and before the config is converted, so that the
    spec and the logged config say the same names and the config is converted once. `screen`: the scene
    build's (scenario/assemble.py `build_scene`), a search's first look at the placed actors."""
    from garage_exp.core.schema_check import check_schema

    check_schema(cfg)  # a key forced past the schema (`+case.bumper_gapp=1`) fails first
    plan_path = resolve_plan_path(cfg.plan)
    prepared = PreparedJob(plan_path, classified_plan(plan_path))
    hand_on(cfg, prepared.classified.plan)
    if name is not None:
        name(cfg, prepared.classified.plan.name)
    config = settings(cfg)  # the layers below are handed plain data, never the config node
    job = check_config(config)  # the scene builder's settings, built once
    from garage_exp.run.spec import job_spec

    detector = None
    if not cfg.dry_run and not hand:  # a search's check judges the scene alone: its job's preflight builds this
        from garage_exp.perception.detect import build_detector
        from garage_exp.slots.detector import check_slot_weights

        detector = build_detector(config.detector)  # a missing file or unknown format fails here (nothing downloaded)
        check_slot_weights(config.slot_detector)
    # A dry run builds the scene description too (~0.1 s, no rendering): it refuses every job the real run would
    # refuse at scene build (placements, overlaps, reach), in the same words. It keeps none of it.
    try:
        scene, setup = scene_of(job, prepared.classified, hand, screen)
    except GarageError as exc:  # a shipped case on a shipped plan it does not fit: say where it fits
        where = hint(cfg.case.name, cfg.plan.name, cfg.plan.file, refused=True)
        if not where:
            raise
        raise exc.again(f"{exc}; {where}", None) from None
    if cfg.export.openscenario:
        from garage_exp.openscenario.checks import check_version

        check_version(str(cfg.export.openscenario_version), setup)
    if not cfg.dry_run:
        prepared.scene, prepared.setup, prepared.detector = scene, setup, detector
    prepared.spec, prepared.config = job_spec(config, detector, job), config
    prepared.bytes_out, prepared.bytes_store = job_bytes(cfg, prepared.scene, prepared.setup)
    if check_space:
        from hydra.core.hydra_config import HydraConfig

        from garage_exp.run.diskspace import check_free

        out = Path(HydraConfig.get().runtime.output_dir) if HydraConfig.initialized() else Path.cwd()
        check_free([(out, prepared.bytes_out), (store_dir(cfg), prepared.bytes_store)], "this job")
    return load_models(prepared) if load else prepared


# A search's requirement check (search/loop.py) builds each draw's scene description to judge it; the draw it
# accepts is then launched as a job whose preflight would build the very same scene again (same settings, same
# plan, same seed: the build is a pure function of them), and a draw whose actors collide (Infeasible) would fail
# the same way twice. The check's preflight (`hand=True`) hands what it built, or the refusal, on to the next
# preflight, which takes it once when its scene settings equal the checked ones and builds the scene otherwise.
_HANDED: dict = STATE.cache("run.preflight.handed", "command")


def scene_of(job, classified, hand: bool = False, screen=None) -> tuple:
    """(scene, setup) of the scene settings `job` on the classified plan: the one handed on for them, else built
    (and handed on itself with `hand`; a build its `screen` stopped hands nothing on)."""
    import numpy as np

    from garage_exp.core.errors import Infeasible
    from garage_exp.scenario.assemble import build_scene

    held = _HANDED.pop("checked", None)
    if held is not None and held[0] is classified:
        if isinstance(held[2], Infeasible):
            if held[1] == job:  # its words may name the file a value came from: the same sources only
                raise held[2]
        elif _same_scene(held[1], job):
            return held[2]
    try:
        built = build_scene(job, classified, _library(), np.random.default_rng(job.seed), screen)
    except Infeasible as exc:
        if hand:
            _HANDED["checked"] = (classified, job, exc)
        raise
    if hand:
        _HANDED["checked"] = (classified, job, built)
    return built


def _same_scene(checked, job) -> bool:
    """Whether the checked settings build the job's scene: equal, but for where the config came from
    (`config_dirs`, `choices`: Hydra's runtime, read only to name a file in an error message), which differ
    between the search's check (the sweep's runtime) and its trial's job (the trial's own); comparing them too
    made every job of the wide space build its scene again (0.07 s a scenario)."""
    if checked == job:
        return True
    if not (is_dataclass(job) and type(checked) is type(job) and hasattr(job, "choices")):
        return False
    return replace(checked, config_dirs=job.config_dirs, choices=job.choices) == job


def load_models(prepared: PreparedJob) -> PreparedJob:
    """The preflight's last check, the only one that loads models: every detector entry loads and answers a
    probe frame of the job's first camera (nothing to load in a dry run)."""
    if prepared.detector is not None and not prepared.loaded:
        prepared.opened = check_loads(prepared.detector, prepared.scene)
        prepared.loaded = True
    return prepared


def check_loads(detector, scene):
    """Every entry of the detector loads and answers a probe frame of the job's first camera, in the process
    that will detect (the detector's child, kept for the job): a file that is not a model is refused before
    anything is written. The opened detector is the one the job's frames go to (not opened again)."""
    from garage_exp.perception.detect.worker import open_detector
    from garage_exp.scene.views import picture_lens

    opened = open_detector(detector, picture_lens(scene.cameras[0]))
    opened.names  # noqa: B018 - waits; raises the load's error
    return opened


def store_dir(cfg: DictConfig) -> Path:
    """Where a local (sqlite) store keeps its database and artifacts; a server's disk is not ours (the
    current dir then, with nothing to write)."""
    import os

    from garage_exp.core.paths import OUTPUTS_DIR
    from garage_exp.tracking.store import sqlite_path

    uri = OmegaConf.select(cfg, "tracking.uri") or os.environ.get("MLFLOW_TRACKING_URI") or \
        f"sqlite:///{OUTPUTS_DIR / 'mlflow.db'}"
    path = sqlite_path(uri)
    return path.parent if path is not None else Path.cwd()


def job_bytes(cfg: DictConfig, scene, setup) -> tuple[int, int]:
    """What a job writes, estimated: (bytes under its output dir, bytes into a local sqlite store and its
    artifacts). A run's artifacts are copies of the job's files; a tracking server keeps them on its own disk."""
    import os

    from garage_exp.run.diskspace import FIXED, PNG_PER_PIXEL, ROW, STORE_FIXED
    from garage_exp.scene.description import Box, Mesh
    from garage_exp.tracking.store import sqlite_path

    out = FIXED
    if scene is not None:
        frames = len(setup.shots) * len(scene.cameras)
        png = PNG_PER_PIXEL * sum(c.width * c.height for c in scene.cameras) / len(scene.cameras)
        glb, meshes = 0, set()
        for entity in scene.entities:
            for shape in entity.shapes:
                if isinstance(shape, Mesh) and shape.path not in meshes:  # the GLB holds a model once
                    meshes.add(shape.path)
                    glb += os.path.getsize(shape.path) if os.path.isfile(shape.path) else 0
                elif isinstance(shape, Box):
                    glb += 1000
        saved = {"all": frames, "key": 3 * len(scene.cameras)}.get(cfg.renderer.save_frames, 0)
        out += glb + ROW * frames + saved * png + (frames * (png + 200) if cfg.get("dataset") else 0)
    uri = OmegaConf.select(cfg, "tracking.uri") or os.environ.get("MLFLOW_TRACKING_URI") or "sqlite:///"
    local = sqlite_path(uri) is not None
    return int(out), int(out + STORE_FIXED) if local else 0
