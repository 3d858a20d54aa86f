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
from garage_exp.scene.boxmesh import UNIT_CORNERS, UNIT_FACES, UNIT_NORMALS, box_uvs, quad
from garage_exp.scene.description import VEHICLE_ROLES, Box, Decal, Entity, Material, Mesh, Pose, Scene

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
    if material.texture is None:
        return PBRMaterial(name=material.name, baseColorFactor=[float(c) for c in material.color],
                           metallicFactor=float(material.metallic), roughnessFactor=float(material.roughness),
                           emissiveFactor=emissive if any(emissive) else None)
    from PIL import Image

    from garage_exp.scene.textures import image, image8

    rgba, _ = image(material)
    blend = bool(np.any(rgba[..., 3] < 1.0))  # decals and see-through signs
    return PBRMaterial(name=material.name, baseColorTexture=Image.fromarray(image8(material)),
                       metallicFactor=float(material.metallic), roughnessFactor=float(material.roughness),
                       emissiveFactor=emissive if any(emissive) else None,
                       alphaMode="BLEND" if blend else "OPAQUE")




def boxes_mesh(boxes: list[tuple[Box | Decal, np.ndarray]]) -> trimesh.Trimesh:
    """One mesh of many boxes (and decals), each (shape, its entity's world transform). Built directly from a
    template: trimesh.creation.box per box costs ~0.3 ms, which adds up to seconds for a big garage. A
    textured material gets the renderer's UVs (scene/boxmesh.py)."""
    vertices, normals, faces, uvs = [], [], [], []
    count = 0
    for shape, transform in boxes:
        m = transform @ pose_matrix(shape.offset)
        tex = shape.material.texture
        if isinstance(shape, Decal):
            corners, tris, norms, uv = quad(shape.size)
        else:
            corners, tris, norms = UNIT_CORNERS * shape.size, UNIT_FACES, UNIT_NORMALS
            uv = None
        world, world_normals = corners @ m[:3, :3].T + m[:3, 3], norms @ m[:3, :3].T
        if uv is None and tex is not None:
            uv = box_uvs(world, world_normals, tex.tile)
        vertices.append(world)
        normals.append(world_normals)
        faces.append(tris + count)
        uvs.append(uv if uv is not None else np.zeros((len(world), 2)))
        count += len(world)
    mesh = trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False,
                           vertex_normals=np.concatenate(normals))
    if boxes and boxes[0][0].material.texture is not None:
        mesh.visual = trimesh.visual.TextureVisuals(uv=np.concatenate(uvs), material=pbr(boxes[0][0].material))
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
    if material.texture is None:
        mesh.visual = trimesh.visual.TextureVisuals(material=pbr(material))
    out.add_geometry(mesh, node_name=name, geom_name=name, parent_node_name=ROOT)


def export_glb(scene: Scene, path: str | Path) -> Path:
    """Write the scene as a .glb (Y up, metres) and return its path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = build_trimesh_scene(scene).export(file_type="glb", include_normals=True)
    path.write_bytes(data)
    return path
