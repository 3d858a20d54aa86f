"""A unit box as a triangle mesh, shared by the glTF export and the renderers that need a box with UVs."""

from __future__ import annotations

import numpy as np


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


def box_uvs(world: np.ndarray, normals: np.ndarray, tile: float) -> np.ndarray:
    """UVs of a box's 24 vertices (world positions, world normals): each face's world coordinates / `tile`
    (tops and bottoms x, y; sides along the face, z), so boxes side by side continue one picture. tile <= 0:
    a sign, its picture once on every face, upright and read from outside (the unit box's own corners)."""
    if tile <= 0:
        c, n = UNIT_CORNERS, UNIT_NORMALS
        across = np.where(np.abs(n[:, 0]) > 0.5, c[:, 1] * n[:, 0], -c[:, 0] * n[:, 1])
        return np.stack([across + 0.5, 0.5 - c[:, 2]], axis=1)
    side = np.stack([np.where(np.abs(normals[:, 0]) > 0.5, world[:, 1], world[:, 0]), world[:, 2]], axis=1)
    return np.where(np.abs(normals[:, 2:3]) > 0.5, world[:, :2], side) / tile


def quad(size) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A decal: a horizontal quad `size` (x, y) metres facing up, its picture spanning it once
    (vertices, triangles, normals, uvs)."""
    hx, hy = float(size[0]) / 2, float(size[1]) / 2
    vertices = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], dtype=float)
    normals = np.tile(np.array([0.0, 0.0, 1.0]), (4, 1))
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]]), normals, uvs
