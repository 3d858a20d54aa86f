"""KITTI object labels and calib files from the scene's ground truth.

KITTI's camera frame is x right, y down, z forward; a label's location is the bottom centre of its 3D box, its
dimensions are height, width, length, and rotation_y turns the box about the (vertical) y axis: 0 when the
object's nose points along +x (right), -pi/2 when it points away from the camera. KITTI's frame is level with
the ground, so a pitched camera cannot be it: the labels use the camera's *level* frame (its position and yaw,
no pitch) and P2 carries the pitch, P2 = K [R | 0]. With the default front camera (pitch 0) R is the identity and
P2 = [K | 0], as in KITTI.

The 2D box is the actor's full (amodal) box within the image, as in the YOLO and COCO files: a projected 3D box
bounds the actor's silhouette, so its corners land on or outside that box: a few pixels for whole actors at a
distance, tens of pixels where the box reaches the floor under a close car's overhang or the actor is cut by the
image edge (README, Dataset exports).
"""

from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from garage_exp.perception.groundtruth import VehicleTruth, local_box
from garage_exp.scene.description import Entity, Pose

# KITTI's classes (Geiger et al.): it has no bus; a pickup goes with trucks, as COCO detectors call it.
KITTI_TYPES = {"car": "Car", "suv": "Car", "van": "Van", "pickup": "Truck", "truck": "Truck", "bus": "Misc",
               "person": "Pedestrian"}
# Our camera frame (SAPIEN's: x forward, y left, z up) -> KITTI's (x right, y down, z forward).
TO_KITTI = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
# KITTI's value for a 3D field it does not know (its DontCare rows).
UNKNOWN_3D = (-1.0, -1.0, -1.0), (-1000.0, -1000.0, -1000.0), -10.0


@dataclass(frozen=True)
class Box3D:
    """One object in the camera's level KITTI frame."""

    dimensions: tuple[float, float, float]  # height, width, length (m)
    location: tuple[float, float, float]  # bottom centre (m)
    rotation_y: float  # radians, [-pi, pi)

    @property
    def alpha(self) -> float:
        """KITTI's observation angle: rotation_y less the ray's angle to the object."""
        x, _, z = self.location
        return _wrap(self.rotation_y - math.atan2(x, z))


def level_rotation(cam_to_world: np.ndarray) -> np.ndarray:
    """World axes -> the camera's level frame (SAPIEN axes): its yaw only. Read from the camera's left axis, which
    pitch leaves level (its forward axis has no heading when it looks straight down)."""
    left = cam_to_world[:3, 1]
    yaw = math.atan2(-left[0], left[1])
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def projection(cam_to_world: np.ndarray, k: np.ndarray) -> np.ndarray:
    """P2 (3 x 4): KITTI level-frame points -> pixels, with the camera's pitch in its rotation; k: the camera
    matrix (scene/lenses' convention, as KITTI's)."""
    # level KITTI -> level SAPIEN -> world -> camera SAPIEN -> camera KITTI
    rot = TO_KITTI @ cam_to_world[:3, :3].T @ level_rotation(cam_to_world).T @ TO_KITTI.T
    return k @ np.hstack([rot, np.zeros((3, 1))])


def box3d(entity: Entity, pose: Pose, cam_to_world: np.ndarray) -> Box3D | None:
    """The actor's 3D box (groundtruth.local_box, placed at `pose`) in the camera's level KITTI frame; None when
    the actor has no box."""
    box = local_box(entity)
    if box is None:
        return None
    lo, hi = box
    length, width, height = hi - lo
    bottom = pose.compose(Pose((lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]))
    level = level_rotation(cam_to_world)
    location = TO_KITTI @ level @ (np.array([bottom.x, bottom.y, bottom.z]) - cam_to_world[:3, 3])
    # The nose's direction, level SAPIEN (cos a, sin a, 0) = KITTI (-sin a, 0, cos a) = (cos ry, 0, -sin ry).
    forward = level @ np.array([math.cos(math.radians(pose.yaw)), math.sin(math.radians(pose.yaw)), 0.0])
    rotation_y = _wrap(math.atan2(-forward[0], -forward[1]))
    return Box3D((float(height), float(width), float(length)), tuple(float(v) for v in location), rotation_y)


def corners(box: Box3D) -> np.ndarray:
    """The 8 corners (8 x 3) of a KITTI box, as KITTI's devkit builds them: bottom face first."""
    h, w, l = box.dimensions
    x = np.array([l, l, -l, -l, l, l, -l, -l]) / 2
    y = np.array([0.0, 0.0, 0.0, 0.0, -h, -h, -h, -h])
    z = np.array([w, -w, -w, w, w, -w, -w, w]) / 2
    c, s = math.cos(box.rotation_y), math.sin(box.rotation_y)
    rot = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    return (rot @ np.vstack([x, y, z])).T + np.asarray(box.location)


def project(p2: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Level-frame points (N x 3) -> pixels (N x 2) with P2 (points in front of the camera)."""
    uvw = np.hstack([points, np.ones((len(points), 1))]) @ p2.T
    return uvw[:, :2] / uvw[:, 2:3]


def label_line(kind: str, truth: VehicleTruth, box: Box3D | None) -> str:
    """One line of a label_2 file: type truncated occluded alpha left top right bottom h w l x y z rotation_y."""
    (h, w, l), (x, y, z), ry = (box.dimensions, box.location, box.rotation_y) if box else UNKNOWN_3D
    alpha = box.alpha if box else -10.0
    x1, y1, x2, y2 = truth.full_box
    return (f"{KITTI_TYPES.get(kind, 'Misc')} {truth.truncation:.2f} {truth.occlusion:d} {alpha:.4f} "
            f"{x1:.2f} {y1:.2f} {x2:.2f} {y2:.2f} {h:.4f} {w:.4f} {l:.4f} {x:.4f} {y:.4f} {z:.4f} {ry:.4f}")


def calib_text(p2: np.ndarray) -> str:
    """A KITTI object calib file. One camera: P0-P3 are all P2. There is no lidar: Tr_velo_to_cam maps a level
    frame at the camera with a lidar's axes (x forward, y left, z up) to the label frame, for tools that read it."""
    velo = np.hstack([TO_KITTI, np.zeros((3, 1))])
    rows = [(f"P{k}", p2) for k in range(4)] + [("R0_rect", np.eye(3)), ("Tr_velo_to_cam", velo),
                                                ("Tr_imu_to_velo", np.hstack([np.eye(3), np.zeros((3, 1))]))]
    return "".join(f"{name}: " + " ".join(f"{v:.12e}" for v in m.ravel()) + "\n" for name, m in rows)


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


class KittiWriter:
    """KITTI's object layout under `root`: image_2 (links to the dataset's images), label_2, calib and
    ImageSets/train.txt, frames numbered 000000, 000001, ... as KITTI's tools expect; frames.csv maps each
    number to the image's name."""

    def __init__(self, root: Path):
        self.root = root
        for sub in ("image_2", "label_2", "calib", "ImageSets"):
            (root / sub).mkdir(parents=True, exist_ok=True)
        self.names: list[str] = []

    def add(self, image: Path, p2: np.ndarray, lines: list[str]) -> str:
        frame_id = f"{len(self.names):06d}"
        self.names.append(image.stem)
        link = self.root / "image_2" / f"{frame_id}{image.suffix}"
        try:
            link.symlink_to(os.path.relpath(image, link.parent))
        except OSError:  # no symlinks (some Windows set-ups): a copy
            shutil.copyfile(image, link)
        (self.root / "label_2" / f"{frame_id}.txt").write_text("".join(line + "\n" for line in lines))
        (self.root / "calib" / f"{frame_id}.txt").write_text(calib_text(p2))
        return frame_id

    def finish(self) -> Path:
        ids = [f"{k:06d}" for k in range(len(self.names))]
        (self.root / "ImageSets" / "train.txt").write_text("".join(i + "\n" for i in ids))
        (self.root / "frames.csv").write_text("kitti_id,image\n" + "".join(
            f"{i},{name}\n" for i, name in zip(ids, self.names)))
        return self.root
