"""Export a scene description to a binary glTF (.glb) a user opens in Blender, Unity or a web viewer.

Boxes become meshes with PBR materials (lamp panels emissive); vehicles are their GLB meshes placed at their
poses. Static boxes are merged per role and material to keep big garages small; pillars and vehicles stay
separate nodes under their entity names so a user can find them. glTF is Y up: a root node turns the
description's Z-up frame into it. Lights and cameras are not exported (the panels show where lamps are).
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

from garage_exp.core.errors import GarageError
from garage_exp.scene.description import VEHICLE_ROLES, Box, Entity, Material, Mesh, Pose, Scene

ROOT = "garage_z_up"
# Z up -> Y up: (x, y, z) -> (x, z, -y), a -90 degree turn about x.
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
SEPARATE = ("pillar_",)  # structure entities a user wants to pick out by name


def pose_matrix(pose: Pose, scale: float = 1.0) -> np.ndarray:
    c, s = math.cos(math.radians(pose.yaw)), math.sin(math.radians(pose.yaw))
    m = np.eye(4)
    m[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) * scale
    m[:3, 3] = (pose.x, pose.y, pose.z)
    return m


def pbr(material: Material) -> PBRMaterial:
    # glTF caps emissiveFactor at 1: brighter panels are scaled down with their hue kept.
    emissive = [max(0.0, float(e)) for e in material.emission]
    peak = max(emissive)
    if peak > 1.0:
        emissive = [e / peak for e in emissive]
    return PBRMaterial(name=material.name, baseColorFactor=[float(c) for c in material.color],
                       metallicFactor=float(material.metallic), roughnessFactor=float(material.roughness),
                       emissiveFactor=emissive if any(emissive) else None)


def _unit_box() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A unit cube with 4 vertices per face (24), so every face keeps its own flat normal."""
    corners, normals, faces = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            u, v = [a for a in range(3) if a != axis]
            quad = []
            for du, dv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = [0.0, 0.0, 0.0]
                p[axis], p[u], p[v] = sign * 0.5, du * 0.5, dv * 0.5
                quad.append(p)
            n = [0.0, 0.0, 0.0]
            n[axis] = sign
            base = len(corners)
            corners += quad
            normals += [n] * 4
            # Counter-clockwise seen from outside: (u, v, axis) is right-handed for the + face.
            right_handed = (u, v, axis) in ((0, 1, 2), (1, 2, 0), (2, 0, 1))
            tris = [(0, 1, 2), (0, 2, 3)] if right_handed == (sign > 0) else [(0, 2, 1), (0, 3, 2)]
            faces += [(base + a, base + b, base + c) for a, b, c in tris]
    return np.array(corners), np.array(normals), np.array(faces)


UNIT_CORNERS, UNIT_NORMALS, UNIT_FACES = _unit_box()


def boxes_mesh(boxes: list[tuple[Box, np.ndarray]]) -> trimesh.Trimesh:
    """One mesh of many boxes, each (box, its entity's world transform). Built directly from a template:
    trimesh.creation.box per box costs ~0.3 ms, which adds up to seconds for a big garage."""
    vertices, normals, faces = [], [], []
    for k, (box, transform) in enumerate(boxes):
        m = transform @ pose_matrix(box.offset)
        vertices.append((UNIT_CORNERS * box.size) @ m[:3, :3].T + m[:3, 3])
        normals.append(UNIT_NORMALS @ m[:3, :3].T)
        faces.append(UNIT_FACES + 24 * k)
    mesh = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False,
                           vertex_normals=np.concatenate(normals))
    return mesh


class _Meshes:
    """Vehicle GLBs loaded once per path and stored once in the output: every car of the same model is a
    node pointing at the same glTF mesh (instancing), so fifty parked cars do not make a file fifty times
    bigger."""

    def __init__(self, out: trimesh.Scene):
        self.out = out
        self.loaded: dict[str, trimesh.Scene] = {}
        self.stored: dict[tuple[str, str], str] = {}  # (path, geometry in its file) -> name in the output

    def _load(self, path: str, entity: str) -> trimesh.Scene:
        if path not in self.loaded:
            if not Path(path).is_file():
                raise GarageError(f"vehicle mesh {path} not found", f"entity {entity}")
            self.loaded[path] = trimesh.load(path, force="scene")
        return self.loaded[path]

    def place(self, entity: Entity, shape: Mesh, k: int) -> None:
        loaded = self._load(shape.path, entity.name)
        place = pose_matrix(entity.pose) @ pose_matrix(shape.offset, shape.scale)
        for node in loaded.graph.nodes_geometry:
            node_transform, geom_name = loaded.graph[node]
            key = (shape.path, geom_name)
            node_name, transform = f"{entity.name}/{k}/{node}", place @ node_transform
            if key in self.stored:
                self.out.graph.update(frame_from=ROOT, frame_to=node_name, matrix=transform,
                                      geometry=self.stored[key])
            else:
                self.stored[key] = f"{Path(shape.path).stem}/{geom_name}"
                self.out.add_geometry(loaded.geometry[geom_name], node_name=node_name, geom_name=self.stored[key],
                                      parent_node_name=ROOT, transform=transform)


def build_trimesh_scene(scene: Scene) -> trimesh.Scene:
    out = trimesh.Scene()
    out.graph.update(frame_from=out.graph.base_frame, frame_to=ROOT, matrix=Z_UP_TO_Y_UP)
    merged: dict[tuple[str, Material], list[tuple[Box, np.ndarray]]] = defaultdict(list)
    meshes = _Meshes(out)
    for entity in scene.entities:
        if not scene.background and entity.role not in VEHICLE_ROLES:
            continue  # the blank control holds the vehicles alone
        own: dict[Material, list[tuple[Box, np.ndarray]]] = defaultdict(list)
        separate = entity.role not in ("structure", "marking", "lamp") or entity.name.startswith(SEPARATE)
        place = pose_matrix(entity.pose)
        for k, shape in enumerate(entity.shapes):
            if isinstance(shape, Mesh):
                meshes.place(entity, shape, k)
                continue
            if separate:
                own[shape.material].append((shape, place))
            else:
                merged[(entity.role, shape.material)].append((shape, place))
        for material, parts in own.items():
            _add_boxes(out, f"{entity.name}/{material.name}", material, parts)
    for (role, material), parts in merged.items():
        _add_boxes(out, f"{role}/{material.name}", material, parts)
    return out


def _add_boxes(out: trimesh.Scene, name: str, material: Material, parts: list[tuple[Box, np.ndarray]]) -> None:
    mesh = boxes_mesh(parts)
    mesh.visual = trimesh.visual.TextureVisuals(material=pbr(material))
    out.add_geometry(mesh, node_name=name, geom_name=name, parent_node_name=ROOT)


def export_glb(scene: Scene, path: str | Path) -> Path:
    """Write the scene as a .glb (Y up, metres) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = build_trimesh_scene(scene).export(file_type="glb", include_normals=True)
    path.write_bytes(data)
    return path
