"""What a camera could see of an actor, from the scene description alone (no pixel rendered).

A scenario space's requirements (`require:`: the target at least so visible, its box at least so tall, within so
many metres) are checked on every draw before it is rendered, as Scenic cuts its prior with `require` and its
visibility checks by casting rays. Here the actor is its 3D box (its extent, as ground truth boxes it) and
everything that can hide it is a box too: the structure's boxes (pillars, walls, obstacle blocks, beams, the
ceiling) and every other actor's extent at the shot's pose. Points spread over the faces of the actor's box that
face the camera are weighted by the solid angle they stand for, and a point counts as seen when it is in the image
and the segment from the camera to it crosses no box. The share of seen weight among the in-image weight is the
estimate of ground truth's visible fraction (visible / unoccluded pixels inside the image).

A car's box is fuller than the car (glass and the gap under the body show what is behind), so the estimate errs
towards "hidden" for what stands behind a car and towards "visible" for a car behind a thin occluder; the measured
fraction after rendering stays the fairness rule that scores a trial (results.table.fair_mask).

Pinhole cameras only: a lens camera (a fisheye) returns None, and its requirements are left to the render.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from garage_exp.perception.groundtruth import local_box, world_corners
from garage_exp.scene.camera import camera_to_world, to_camera
from garage_exp.scene.lenses import Pinhole, lens_of
from garage_exp.scene.description import Box, CameraSpec, Entity, Pose, Scene

NEAR = 0.05  # m: the cameras' near plane (CameraSpec.near)
PER_FACE = 7  # sample points per side of each face: 49 a face, at most 3 faces face a camera
SKIP_ROLES = ("marking", "lamp")  # flat paint and lamp panels under the ceiling hide nothing worth a ray


@dataclass(frozen=True)
class Sight:
    """The estimate for one actor in one camera: `distance` camera centre to the box centre (m), `box_height` the
    projected 3D box's height inside the image (px, 0 when outside), `visible` the share of its in-image surface
    that no box hides (0 when none of it is in the image), `truncation` the share of the projected box's rectangle
    outside the image (ground truth's, perception/groundtruth.projected_truncation)."""

    distance: float
    box_height: float
    visible: float
    truncation: float = 0.0


@dataclass(frozen=True)
class Boxes:
    """Oriented boxes as arrays: centres (N x 3), half sizes (N x 3), yaw (N, radians); and their world AABBs."""

    centre: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    lo: np.ndarray
    hi: np.ndarray

    @classmethod
    def of(cls, items: list[tuple[np.ndarray, np.ndarray, float]]) -> "Boxes":
        if not items:
            empty = np.zeros((0, 3))
            return cls(empty, empty, np.zeros(0), empty, empty)
        centre = np.array([c for c, _, _ in items], dtype=float)
        half = np.array([h for _, h, _ in items], dtype=float)
        yaw = np.array([y for _, _, y in items], dtype=float)
        c, s = np.abs(np.cos(yaw)), np.abs(np.sin(yaw))
        reach = np.stack([c * half[:, 0] + s * half[:, 1], s * half[:, 0] + c * half[:, 1], half[:, 2]], axis=1)
        return cls(centre, half, yaw, centre - reach, centre + reach)

    def __len__(self) -> int:
        return len(self.yaw)

    def near(self, lo: np.ndarray, hi: np.ndarray) -> "Boxes":
        """The boxes whose world AABB meets the AABB lo..hi (the only ones a segment inside it can cross)."""
        keep = np.all((self.lo <= hi) & (self.hi >= lo), axis=1)
        return Boxes(self.centre[keep], self.half[keep], self.yaw[keep], self.lo[keep], self.hi[keep])

    def __add__(self, other: "Boxes") -> "Boxes":
        return Boxes(*(np.concatenate([a, b]) for a, b in zip(
            (self.centre, self.half, self.yaw, self.lo, self.hi),
            (other.centre, other.half, other.yaw, other.lo, other.hi))))


def entity_boxes(entity: Entity, pose: Pose | None = None) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """An entity's boxes in the world: an actor's extent box (as ground truth boxes it), else its Box shapes."""
    pose = entity.pose if pose is None else pose
    yaw = np.radians(pose.yaw)
    if entity.extent is not None:
        lo, hi = local_box(entity)
        return [(_placed((lo + hi) / 2, pose), (hi - lo) / 2, yaw)]
    out = []
    for shape in entity.shapes:
        if isinstance(shape, Box):
            local = np.array([shape.offset.x, shape.offset.y, shape.offset.z])
            out.append((_placed(local, pose), np.asarray(shape.size, float) / 2, yaw + np.radians(shape.offset.yaw)))
    return out


def static_boxes(scene: Scene, skip: tuple[str, ...] = ()) -> Boxes:
    """Every box of the scene's entities that may hide something, but the named ones (the case's actors, which
    move from shot to shot) and flat or tiny things (SKIP_ROLES)."""
    items = []
    for entity in scene.entities:
        if entity.role in SKIP_ROLES or entity.name in skip:
            continue
        items += entity_boxes(entity)
    return Boxes.of(items)


def sight(static: Boxes, actors: Mapping[str, tuple[Entity, Pose]], target: str, ego: Pose,
          camera: CameraSpec) -> Sight | None:
    """The estimate for actor `target` (a key of `actors`: each case actor's entity and pose in this shot) seen by
    `camera` on the ego at `ego`. Every actor but the target hides what is behind it (the ego too: a reversing
    camera's view passes its own bumper). None for a lens camera (module doc)."""
    if camera.fisheye:
        return None
    entity, pose = actors[target]
    corners = world_corners(entity, pose)
    if corners is None:
        return None
    cam = camera_to_world(ego, camera)
    origin = cam[:3, 3]
    lens = lens_of(camera)
    centre = corners.mean(axis=0)
    distance = float(np.linalg.norm(centre - origin))
    height, truncation = _box_height(to_camera(cam, corners), lens, camera)
    points, weight = _face_samples(entity, pose, origin)
    local = to_camera(cam, points)
    front = local[:, 0] > NEAR
    u, v = lens.pixels(local[front])
    inside = np.zeros(len(points), bool)
    inside[front] = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    total = float(weight[inside].sum())
    if total <= 0:
        return Sight(distance, height, 0.0, truncation)
    movers = Boxes.of([b for name, (e, p) in actors.items() if name != target and p is not None
                       for b in entity_boxes(e, p)])
    points = points[inside]
    lo, hi = np.minimum(points.min(axis=0), origin), np.maximum(points.max(axis=0), origin)
    hit = _blocked(origin, points, (static + movers).near(lo, hi))
    return Sight(distance, height, float(weight[inside][~hit].sum() / total), truncation)


def _placed(local: np.ndarray, pose: Pose) -> np.ndarray:
    c, s = np.cos(np.radians(pose.yaw)), np.sin(np.radians(pose.yaw))
    return np.array([pose.x + c * local[0] - s * local[1], pose.y + s * local[0] + c * local[1], pose.z + local[2]])


def _box_height(local: np.ndarray, lens: Pinhole, camera: CameraSpec) -> tuple[float, float]:
    """The projected box's height in pixels inside the image (ground truth's full box stops at the border; a box
    wholly left or right of the image has none), and the share of its rectangle outside the image."""
    from garage_exp.perception.groundtruth import _clip_near, _outside

    points = _clip_near(local, NEAR)
    if len(points) == 0:
        return 0.0, 1.0
    u, v = lens.pixels(points)
    truncation = _outside(u, v, camera.width, camera.height)
    if u.max() <= 0 or u.min() >= camera.width:
        return 0.0, truncation
    top, bottom = max(float(v.min()), 0.0), min(float(v.max()), float(camera.height))
    return max(bottom - top, 0.0), truncation


def _face_samples(entity: Entity, pose: Pose, eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points on the faces of the actor's box that face the eye, pulled 1 cm inside the box (so that the box's own
    faces never count as hiding it), each weighted by the solid angle its patch stands for."""
    lo, hi = local_box(entity)
    size = hi - lo
    yaw = np.radians(pose.yaw)
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    eye_local = (eye - np.array([pose.x, pose.y, pose.z])) @ rot
    t = (np.arange(PER_FACE) + 0.5) / PER_FACE
    points, weights = [], []
    for axis in range(3):
        for side, face in ((-1, lo[axis]), (1, hi[axis])):
            if (eye_local[axis] - face) * side <= 0:  # the eye is behind this face's plane
                continue
            a, b = [k for k in range(3) if k != axis]
            grid = np.zeros((PER_FACE * PER_FACE, 3))
            grid[:, a] = np.repeat(lo[a] + t * size[a], PER_FACE)
            grid[:, b] = np.tile(lo[b] + t * size[b], PER_FACE)
            grid[:, axis] = face - side * 0.01
            ray = grid - eye_local
            dist = np.linalg.norm(ray, axis=1)
            cos = np.abs(ray[:, axis]) / np.maximum(dist, 1e-9)
            patch = size[a] * size[b] / PER_FACE ** 2
            points.append(grid)
            weights.append(patch * cos / np.maximum(dist, 1e-9) ** 2)
    if not points:  # the eye inside the box
        return np.zeros((0, 3)), np.zeros(0)
    local = np.concatenate(points)
    return local @ rot.T + np.array([pose.x, pose.y, pose.z]), np.concatenate(weights)


def _blocked(origin: np.ndarray, points: np.ndarray, boxes: Boxes) -> np.ndarray:
    """For each point, whether the segment origin -> point crosses any of the boxes (the slab test, in each box's
    own frame; P points x B boxes at once)."""
    if len(boxes) == 0 or len(points) == 0:
        return np.zeros(len(points), bool)
    c, s = np.cos(boxes.yaw), np.sin(boxes.yaw)  # (B,)
    # Segment ends in each box's frame: rotate by -yaw about the box's centre. Shapes (B, 3) and (P, B, 3).
    o = origin[None, :] - boxes.centre
    o = np.stack([c * o[:, 0] + s * o[:, 1], -s * o[:, 0] + c * o[:, 1], o[:, 2]], axis=1)
    d = points[:, None, :] - origin[None, None, :]
    d = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1],
                  np.broadcast_to(d[..., 2], (len(points), len(c)))], axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-boxes.half[None] - o[None]) * inv
        t2 = (boxes.half[None] - o[None]) * inv
    # An axis the segment runs parallel to: inside the slab it never limits t, outside it misses the box.
    parallel = d == 0
    inside = np.abs(o[None]) <= boxes.half[None]
    t1 = np.where(parallel, np.where(inside, -np.inf, np.inf), t1)
    t2 = np.where(parallel, np.where(inside, np.inf, -np.inf), t2)
    enter = np.minimum(t1, t2).max(axis=2)
    leave = np.maximum(t1, t2).min(axis=2)
    hit = (enter <= leave) & (leave > 0.0) & (enter < 1.0)
    return hit.any(axis=1)
