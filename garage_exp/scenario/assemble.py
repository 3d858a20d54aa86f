"""The scene description a job renders: the garage built from the plan, the case's actors, parked cars by
occupancy, the camera rig and the scene modifiers. Plain data: nothing here renders."""

from __future__ import annotations


from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Classified
from garage_exp.scenario import CaseSetup, make_case
from garage_exp.scene.camera import rig_specs
from garage_exp.scene.description import CameraSpec, Pose, Scene

HIDDEN = Pose(0.0, 0.0, -500.0, 0.0)  # vehicles a shot does not use wait far below the floor


def build_scene(cfg, classified: Classified, library, rng) -> tuple[Scene, CaseSetup]:
    """The garage from the plan, the case's vehicles, parked cars by occupancy, cameras and modifiers."""
    from garage_exp.scene.look import dress
    from garage_exp.scene.modifiers import apply_modifiers, remove_entity, resize_pillar
    from garage_exp.scene.parking import park_vehicles
    from garage_exp.scene.structure import build_garage

    scene = build_garage(classified, cfg.garage, cfg.light)
    apply_modifiers(scene, classified, cfg.garage, cfg.get("modifiers") or {})
    setup = make_case(cfg, classified, library, rng)
    if setup.occluder:
        if cfg.occluder.kind == "none":
            remove_entity(scene, setup.occluder)
        elif cfg.occluder.kind != "pillar":
            raise GarageError(f"unknown occluder kind {cfg.occluder.kind!r} (pillar | none)", "occluder.kind")
        elif cfg.occluder.size is not None:
            resize_pillar(scene, setup.occluder, cfg.occluder.size, classified)
    scene.entities.extend(setup.vehicles)
    if cfg.palette.parked_occupancy > 0:
        scene.entities.extend(park_vehicles(classified, cfg.garage, cfg.palette, library, rng, scene,
                                            exclude=setup.used_bays))
    dress(scene, classified, cfg.garage, cfg.look, cfg.materials, cfg.clutter, int(cfg.seed), marking_wear(cfg))
    scene.cameras = cameras(cfg, setup)
    scene.background = not cfg.blank
    return scene, setup


def marking_wear(cfg) -> float:
    """How worn the line paint is by the `wear` factor (its modifier's value, else the garage's)."""
    wear = (cfg.get("modifiers") or {}).get("wear") or {}
    return float(wear.get("wear", cfg.garage.marking_wear))


def cameras(cfg, setup: CaseSetup) -> list[CameraSpec]:
    ego = next(v for v in setup.vehicles if v.role == "ego")
    return rig_specs(cfg.camera, ego.extent)
