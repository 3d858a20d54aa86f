"""A small reader for AC3D (.ac) files, the format of FlightGear's vehicles.

trimesh has no AC3D loader and SAPIEN's (assimp) needs a renderer, so this turns an .ac file into a
`trimesh.Scene` with UVs, normals (honouring `crease`) and PBR materials carrying the PNG texture: enough for
glTF export and for geometry checks without SAPIEN.

Format notes (https://www.inivis.com/ac3d/man/ac3dfileformat.html): vertices are local to their OBJECT;
`rot` (3x3, row-major) and `loc` place an object in its parent (v' = rot @ v + loc); `texrep`/`texoff` map a
surface's UVs as uv * texrep + texoff; the low nibble of a SURF's flags is its type (0 polygon, 1 closed
line, 2 line), bit 0x10 smooth shading, bit 0x20 two-sided. FlightGear groups named "LOD near/far" hold
levels of detail that a viewer shows one at a time.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator

import numpy as np

from garage_exp.core.errors import GarageError

log = logging.getLogger(__name__)

# AC3D's own default when an object has no `crease` line.
DEFAULT_CREASE_DEG = 61.0
SURF_POLYGON = 0x0
SURF_SMOOTH = 0x10
SURF_TWO_SIDED = 0x20
_LOD_NAME = re.compile(r"^LOD\s+([-+0-9.eE]+)\s*/\s*([-+0-9.eE]+)")


@dataclass
class AcMaterial:
    name: str
    rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    amb: tuple[float, float, float] = (0.2, 0.2, 0.2)
    emis: tuple[float, float, float] = (0.0, 0.0, 0.0)
    spec: tuple[float, float, float] = (0.0, 0.0, 0.0)
    shi: float = 64.0
    trans: float = 0.0


@dataclass
class AcSurface:
    flags: int
    material: int
    refs: np.ndarray  # (k,) vertex indices into the object's vertices
    uvs: np.ndarray  # (k, 2)

    @property
    def is_polygon(self) -> bool:
        return self.flags & 0xF == SURF_POLYGON


@dataclass
class AcObject:
    kind: str  # world, group, poly, light
    name: str = ""
    data: str = ""
    texture: str | None = None
    texrep: tuple[float, float] = (1.0, 1.0)
    texoff: tuple[float, float] = (0.0, 0.0)
    crease: float = DEFAULT_CREASE_DEG
    loc: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rot: np.ndarray = field(default_factory=lambda: np.eye(3))
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    surfaces: list[AcSurface] = field(default_factory=list)
    kids: list["AcObject"] = field(default_factory=list)

    def local_matrix(self) -> np.ndarray:
        m = np.eye(4)
        m[:3, :3] = self.rot
        m[:3, 3] = self.loc
        return m

    def walk(self, parent: np.ndarray | None = None) -> Iterator[tuple["AcObject", np.ndarray]]:
        """Every object below (and including) this one with its object-to-file 4x4 transform."""
        world = (np.eye(4) if parent is None else parent) @ self.local_matrix()
        yield self, world
        for kid in self.kids:
            yield from kid.walk(world)

    @property
    def lod_range(self) -> tuple[float, float] | None:
        """(near, far) for a FlightGear LOD group, else None."""
        match = _LOD_NAME.match(self.name) if self.kind == "group" else None
        return (float(match.group(1)), float(match.group(2))) if match else None

    def face_count(self) -> int:
        return sum(len(s.refs) >= 3 and s.is_polygon for o, _ in self.walk() for s in o.surfaces)


@dataclass
class AcFile:
    path: Path
    materials: list[AcMaterial]
    world: AcObject


class _Lines:
    """The file's lines with a cursor; errors name the file and line."""

    def __init__(self, path: Path, text: str):
        self.path = path
        self.lines = text.splitlines()
        self.i = 0

    def next(self) -> str:
        while self.i < len(self.lines):
            line = self.lines[self.i].strip()
            self.i += 1
            if line:
                return line
        raise self.error("unexpected end of file")

    def raw(self) -> str:
        if self.i >= len(self.lines):
            raise self.error("unexpected end of file in a data block")
        self.i += 1
        return self.lines[self.i - 1]

    def at_end(self) -> bool:
        return all(not line.strip() for line in self.lines[self.i:])

    def error(self, message: str) -> GarageError:
        return GarageError(message, f"{self.path}:{self.i}")


def _quoted(line: str, keyword: str) -> str:
    rest = line[len(keyword):].strip()
    return rest[1:-1] if len(rest) >= 2 and rest[0] == rest[-1] == '"' else rest


def _floats(lines: _Lines, parts: list[str], count: int) -> tuple[float, ...]:
    try:
        values = tuple(float(p) for p in parts[:count])
    except ValueError:
        raise lines.error(f"expected {count} numbers after {parts[0] if parts else '?'}") from None
    if len(values) != count:
        raise lines.error(f"expected {count} numbers")
    return values


def _parse_material(lines: _Lines, line: str) -> AcMaterial:
    # MATERIAL "name" rgb r g b amb r g b emis r g b spec r g b shi n trans t
    match = re.match(r'MATERIAL\s+"([^"]*)"\s*(.*)$', line)
    if not match:
        raise lines.error("bad MATERIAL line")
    tokens = match.group(2).split()
    values: dict[str, list[float]] = {}
    key = None
    for token in tokens:
        try:
            number = float(token)
        except ValueError:
            key = token
            values[key] = []
            continue
        if key is None:
            raise lines.error("MATERIAL value before any key")
        values[key].append(number)
    mat = AcMaterial(match.group(1))
    for key in ("rgb", "amb", "emis", "spec"):
        if key in values:
            if len(values[key]) != 3:
                raise lines.error(f"MATERIAL {key} needs 3 numbers")
            setattr(mat, key, tuple(values[key]))
    if values.get("shi"):
        mat.shi = values["shi"][0]
    if values.get("trans"):
        mat.trans = values["trans"][0]
    return mat


def _parse_surface(lines: _Lines, header: str) -> AcSurface:
    try:
        flags = int(header.split()[1], 0)
    except (IndexError, ValueError):
        raise lines.error("bad SURF line") from None
    material = 0
    while True:
        parts = lines.next().split()
        if parts[0] == "mat":
            material = int(parts[1])
        elif parts[0] == "refs":
            count = int(parts[1])
            break
        else:
            raise lines.error(f"unexpected '{parts[0]}' in a SURF")
    refs = np.empty(count, dtype=np.int64)
    uvs = np.zeros((count, 2))
    for k in range(count):
        parts = lines.next().split()
        try:
            refs[k] = int(parts[0])
            if len(parts) >= 3:
                uvs[k] = float(parts[1]), float(parts[2])
        except (IndexError, ValueError):
            raise lines.error("bad vertex reference in a SURF") from None
    return AcSurface(flags, material, refs, uvs)


def _parse_object(lines: _Lines, header: str) -> AcObject:
    parts = header.split()
    if len(parts) < 2:
        raise lines.error("OBJECT without a type")
    obj = AcObject(kind=parts[1])
    while True:
        line = lines.next()
        parts = line.split()
        key = parts[0]
        if key == "name":
            obj.name = _quoted(line, "name")
        elif key == "data":
            # `data N` is followed by exactly N characters, which may span lines.
            length = int(parts[1])
            chunk = lines.raw()
            while len(chunk) < length:
                chunk += "\n" + lines.raw()
            obj.data = chunk[:length]
        elif key == "texture":
            obj.texture = _quoted(line, "texture")
        elif key == "texrep":
            obj.texrep = _floats(lines, parts[1:], 2)
        elif key == "texoff":
            obj.texoff = _floats(lines, parts[1:], 2)
        elif key == "crease":
            obj.crease = _floats(lines, parts[1:], 1)[0]
        elif key == "loc":
            obj.loc = np.array(_floats(lines, parts[1:], 3))
        elif key == "rot":
            obj.rot = np.array(_floats(lines, parts[1:], 9)).reshape(3, 3)
        elif key == "numvert":
            count = int(parts[1])
            verts = [lines.next().split()[:3] for _ in range(count)]
            try:
                obj.vertices = np.array(verts, dtype=float).reshape(count, 3)
            except ValueError:
                raise lines.error("bad vertex line") from None
        elif key == "numsurf":
            for _ in range(int(parts[1])):
                surf_header = lines.next()
                if not surf_header.startswith("SURF"):
                    raise lines.error(f"expected SURF, got '{surf_header.split()[0]}'")
                obj.surfaces.append(_parse_surface(lines, surf_header))
        elif key == "kids":
            # `kids` closes an object's header: its children follow.
            for _ in range(int(parts[1])):
                if lines.at_end():
                    # motorhome.ac declares 4 kids and holds 1: keep what is there, as assimp does.
                    log.warning("%s: object '%s' declares %s kids, file ends after %d", lines.path, obj.name,
                                parts[1], len(obj.kids))
                    break
                kid_header = lines.next()
                if not kid_header.startswith("OBJECT"):
                    raise lines.error(f"expected OBJECT, got '{kid_header.split()[0]}'")
                obj.kids.append(_parse_object(lines, kid_header))
            return obj
        # Other keys (url, subdiv, hidden, locked, folded) do not change geometry or looks.


def read_ac(path: str | Path) -> AcFile:
    """Parse an .ac file; GarageError naming the file and line when it is not valid AC3D."""
    path = Path(path)
    try:
        text = path.read_text(encoding="latin-1")  # material names hold German umlauts in Latin-1
    except OSError as exc:
        raise GarageError(f"cannot read: {exc.strerror}", str(path)) from None
    lines = _Lines(path, text)
    if not lines.next().startswith("AC3D"):
        raise GarageError("not an AC3D file (no AC3D header)", str(path))
    materials: list[AcMaterial] = []
    world = None
    try:
        while not lines.at_end():
            line = lines.next()
            if line.startswith("MATERIAL"):
                materials.append(_parse_material(lines, line))
            elif line.startswith("OBJECT"):
                kid = _parse_object(lines, line)
                if world is None:
                    world = kid
                else:
                    world.kids.append(kid)
            else:
                raise lines.error(f"unexpected '{line.split()[0]}' at top level")
    except (ValueError, IndexError):
        raise lines.error("malformed line") from None
    if world is None:
        raise GarageError("no OBJECT in file", str(path))
    return AcFile(path, materials, world)


def nearest_lod(obj: AcObject) -> AcObject:
    """A copy of the tree keeping, among sibling LOD groups, only the nearest one (the most detailed).

    Siblings starting at the same distance keep the one with the most faces; groups that are not LODs stay.
    """
    lods = [k for k in obj.kids if k.lod_range is not None and k.face_count() > 0]
    keep = None
    if len(lods) > 1:
        keep = min(lods, key=lambda k: (k.lod_range[0], -k.face_count()))
    kids = [nearest_lod(k) for k in obj.kids if k.lod_range is None or keep is None or k is keep]
    return replace(obj, kids=kids)


def lod_groups(obj: AcObject) -> list[AcObject]:
    """The LOD groups with geometry anywhere in the tree."""
    return [o for o, _ in obj.walk() if o.lod_range is not None and o.face_count() > 0]


@dataclass
class MeshPart:
    """Triangles of one object sharing one material, texture and sidedness, in file coordinates."""

    vertices: np.ndarray  # (n, 3)
    faces: np.ndarray  # (m, 3)
    uvs: np.ndarray  # (n, 2)
    normals: np.ndarray  # (n, 3)
    material: int
    texture: str | None
    two_sided: bool


def _triangulate(obj: AcObject) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fan-triangulate the polygons: corner vertex ids (t,3), corner UVs (t,3,2), material (t,), flags (t,)."""
    tris, uvs, mats, flags = [], [], [], []
    for surf in obj.surfaces:
        if not surf.is_polygon or len(surf.refs) < 3:
            continue  # lines carry no surface to render
        # AC3D car faces are small convex polygons: a fan from the first corner is exact for them.
        for k in range(1, len(surf.refs) - 1):
            idx = [0, k, k + 1]
            tris.append(surf.refs[idx])
            uvs.append(surf.uvs[idx])
            mats.append(surf.material)
            flags.append(surf.flags)
    if not tris:
        return np.zeros((0, 3), int), np.zeros((0, 3, 2)), np.zeros(0, int), np.zeros(0, int)
    return np.array(tris), np.array(uvs), np.array(mats), np.array(flags)


def _corner_normals(positions: np.ndarray, tris: np.ndarray, smooth: np.ndarray, crease_deg: float) -> np.ndarray:
    """A normal per triangle corner: the face normal, or for smooth faces the area-weighted mean of the
    normals of faces around the same position that lie within the crease angle."""
    cross = np.cross(positions[tris[:, 1]] - positions[tris[:, 0]], positions[tris[:, 2]] - positions[tris[:, 0]])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    unit = np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)
    normals = np.repeat(unit[:, None, :], 3, axis=1)
    # Modellers duplicate vertices along seams, so smooth across equal positions, not equal indices.
    _, pos_id = np.unique(np.round(positions, 6), axis=0, return_inverse=True)
    pos_id = pos_id.reshape(-1)
    corner_pos = pos_id[tris].reshape(-1)
    corner_tri = np.repeat(np.arange(len(tris)), 3)
    order = np.argsort(corner_pos, kind="stable")
    bounds = np.flatnonzero(np.diff(corner_pos[order])) + 1
    cos_crease = np.cos(np.radians(crease_deg))
    flat = normals.reshape(-1, 3)
    for group in np.split(order, bounds):
        if len(group) < 2:
            continue
        faces = corner_tri[group]
        dots = unit[faces] @ unit[faces].T
        weights = (dots >= cos_crease - 1e-9).astype(float)
        summed = weights @ cross[faces]
        norm = np.linalg.norm(summed, axis=1, keepdims=True)
        smoothed = np.divide(summed, norm, out=unit[faces].copy(), where=norm > 0)
        keep = smooth[faces]
        flat[group[keep]] = smoothed[keep]
    return flat.reshape(-1, 3, 3)


def mesh_parts(ac: AcFile, root: AcObject | None = None) -> list[MeshPart]:
    """Triangle meshes of every poly object below root (default: the whole file), in file coordinates."""
    parts = []
    for obj, matrix in (root or ac.world).walk():
        if obj.kind != "poly" or not obj.surfaces or len(obj.vertices) == 0:
            continue
        tris, corner_uv, mats, flags = _triangulate(obj)
        if len(tris) == 0:
            continue
        if tris.max() >= len(obj.vertices) or tris.min() < 0:
            raise GarageError(f"object '{obj.name}' refers to a vertex it does not have", str(ac.path))
        positions = obj.vertices @ matrix[:3, :3].T + matrix[:3, 3]
        # Zero-area triangles (collinear corners, common in truck models) cover nothing and have no normal.
        edges = np.cross(obj.vertices[tris[:, 1]] - obj.vertices[tris[:, 0]],
                         obj.vertices[tris[:, 2]] - obj.vertices[tris[:, 0]])
        keep = np.linalg.norm(edges, axis=1) > 0
        tris, corner_uv, mats, flags = tris[keep], corner_uv[keep], mats[keep], flags[keep]
        if len(tris) == 0:
            continue
        corner_uv = corner_uv * np.array(obj.texrep) + np.array(obj.texoff)
        normals = _corner_normals(positions, tris, (flags & SURF_SMOOTH) != 0, obj.crease)
        two_sided = (flags & SURF_TWO_SIDED) != 0
        for mat in np.unique(mats):
            for sided in (False, True):
                sel = (mats == mat) & (two_sided == sided)
                if sel.any():
                    parts.append(_weld(positions, tris[sel], corner_uv[sel], normals[sel], int(mat), obj.texture,
                                       sided))
    return parts


def _weld(positions, tris, corner_uv, normals, material, texture, two_sided) -> MeshPart:
    """One vertex per distinct (position, uv, normal): shared where the surface is continuous."""
    keys = np.concatenate([tris.reshape(-1, 1).astype(float), np.round(corner_uv.reshape(-1, 2), 6),
                           np.round(normals.reshape(-1, 3), 4)], axis=1)
    unique, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    return MeshPart(vertices=positions[tris.reshape(-1)[first]], faces=inverse.reshape(-1, 3),
                    uvs=corner_uv.reshape(-1, 2)[first], normals=normals.reshape(-1, 3)[first], material=material,
                    texture=texture, two_sided=two_sided)


def roughness(mat: AcMaterial) -> float:
    """Phong shininess and specular strength as a PBR roughness: glossy only where spec is strong."""
    glossy = 1.0 - np.sqrt(2.0 / (max(mat.shi, 0.0) + 2.0))
    return float(np.clip(1.0 - float(np.mean(mat.spec)) * glossy, 0.05, 1.0))


def to_scene(ac: AcFile, parts: list[MeshPart] | None = None, transform: np.ndarray | None = None):
    """A trimesh.Scene of the parts (default: all of the file), optionally moved by a 4x4 transform.

    Each part becomes a Trimesh with UVs, normals and a PBR material: baseColorTexture from the PNG beside the
    file, baseColorFactor from the material's rgb (AC3D modulates the texture by it), emission as given.
    """
    import trimesh
    from PIL import Image

    parts = mesh_parts(ac) if parts is None else parts
    transform = np.eye(4) if transform is None else transform
    images: dict[str, Image.Image] = {}
    scene = trimesh.Scene()
    for n, part in enumerate(parts):
        if part.material >= len(ac.materials):
            raise GarageError(f"surface uses material {part.material}, file has {len(ac.materials)}", str(ac.path))
        mat = ac.materials[part.material]
        image = None
        if part.texture:
            if part.texture not in images:
                tex_path = ac.path.parent / part.texture
                try:
                    images[part.texture] = Image.open(tex_path).convert("RGBA" if _has_alpha(tex_path) else "RGB")
                except OSError:
                    raise GarageError(f"texture '{part.texture}' is missing or unreadable", str(ac.path)) from None
            image = images[part.texture]
        material = trimesh.visual.material.PBRMaterial(
            name=mat.name,
            baseColorFactor=[*mat.rgb, 1.0 - mat.trans],
            baseColorTexture=image,
            emissiveFactor=list(mat.emis),
            metallicFactor=0.0,
            roughnessFactor=roughness(mat),
            doubleSided=part.two_sided,
            alphaMode="BLEND" if mat.trans > 0 else None,
        )
        vertices = part.vertices @ transform[:3, :3].T + transform[:3, 3]
        normals = part.normals @ transform[:3, :3].T
        # A scaled transform scales normals too; rotations plus uniform scale keep their directions.
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = np.divide(normals, length, out=np.zeros_like(normals), where=length > 0)
        mesh = trimesh.Trimesh(vertices=vertices, faces=part.faces, vertex_normals=normals,
                               visual=trimesh.visual.TextureVisuals(uv=part.uvs, material=material), process=False)
        scene.add_geometry(mesh, geom_name=f"part{n:03d}")
    return scene


def _has_alpha(path: Path) -> bool:
    from PIL import Image

    with Image.open(path) as img:
        return img.mode in ("RGBA", "LA") or (img.mode == "P" and "transparency" in img.info)


def load_ac(path: str | Path, lod: str = "nearest"):
    """Read an .ac file as a trimesh.Scene; lod='nearest' drops the farther levels of detail, 'all' keeps them."""
    ac = read_ac(path)
    root = nearest_lod(ac.world) if lod == "nearest" else ac.world
    return to_scene(ac, mesh_parts(ac, root))
