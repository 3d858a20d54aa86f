"""The scene description a job renders: the garage built from the plan, the case's actors, parked cars by
occupancy, the camera rig and the scene modifiers. Plain data: nothing here renders."""

from __future__ import annotations


from garage_exp.core.errors import GarageError
from garage_exp.plan.classify import Classified
from garage_exp.scenario import CaseSetup, make_case
from garage_exp.scenario.spec import SceneSpec
from garage_exp.scene.camera import rig_specs
from garage_exp.scene.description import CameraSpec, Pose, Scene

HIDDEN = Pose(0.0, 0.0, -500.0, 0.0)  # vehicles a shot does not use wait far below the floor


def build_scene(job: SceneSpec, classified: Classified, library, rng, screen=None) -> tuple[Scene, CaseSetup]:
    """The garage from the plan, the case's vehicles, parked cars by occupancy, cameras and modifiers.
    `screen(job, setup, cameras)`, when given, sees the placed actors and their cameras before the garage is
    built, and may stop the build by raising `Screened` (a search's requirements: most rejections need no
    garage)."""
    from garage_exp.scene.look import dress
    from garage_exp.scene.modifiers import apply_modifiers, remove_entity, resize_pillar
    from garage_exp.scene.parking import park_vehicles
    from garage_exp.scene.structure import build_garage

    # The case first: it reads the plan, never the built garage, and refuses actors that overlap (Infeasible) -
    # a third of a wide search's draws, each then spared building the garage it would not use.
    setup = make_case(job, classified, library, rng)
    rig = cameras(job, setup)  # the ego's, placed by the case: what the screen looks through, and the scene's
    if screen is not None:
        screen(job, setup, rig)  # reads the set-up, draws no random number: the build is unchanged
    scene = build_garage(classified, job.garage, job.light)
    if job.blank:
        studio_light(scene, classified, job)
    apply_modifiers(scene, classified, job.garage, job.modifiers)
    if setup.occluder:
        if job.occluder.kind == "none":
            remove_entity(scene, setup.occluder)
        elif job.occluder.kind != "pillar":
            raise GarageError(f"unknown occluder kind {job.occluder.kind!r} (pillar | none)", "occluder.kind")
        elif job.occluder.size is not None:
            resize_pillar(scene, setup.occluder, job.occluder.size, classified)
    scene.entities.extend(setup.vehicles)
    if job.palette.parked_occupancy > 0:
        scene.entities.extend(park_vehicles(classified, job.garage, job.palette, library, rng, scene,
                                            exclude=setup.used_bays))
    dress(scene, classified, job.garage, job.look, job.materials, job.clutter, int(job.seed), marking_wear(job))
    scene.cameras = rig
    scene.background = not job.blank
    return scene, setup


def studio_light(scene: Scene, classified: Classified, job: SceneSpec) -> None:
    """The blank control's light: the look's `blank_light` preset whatever the job's `light` (the research's
    blank is a clean, evenly lit render of the car that hardly moves with the light); none: the job's preset."""
    from garage_exp.scene.lamps import build_lamps

    light = job.look.blank_light
    if light is not None:
        _, scene.lights = build_lamps(classified, job.garage, light)
        scene.ambient = (float(light.ambient),) * 3


def marking_wear(job: SceneSpec) -> float:
    """How worn the line paint is by the `wear` factor (its modifier's value, else the garage's)."""
    wear = job.modifiers.get("wear") or {}  # a modifier's spec: plain data
    return float(wear.get("wear", job.garage.marking_wear))


def cameras(job: SceneSpec, setup: CaseSetup) -> list[CameraSpec]:
    ego = next(v for v in setup.vehicles if v.role == "ego")
    return rig_specs(job.camera, ego.extent)
