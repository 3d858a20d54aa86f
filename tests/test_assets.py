"""The vehicle asset library: AC3D reader, conversion to GLB, classification, choice, data lookup."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import require

from garage_exp.core import paths
from garage_exp.assets import ac3d, locate, vehicles
from garage_exp.assets.vehicles import VehicleLibrary
from garage_exp.core.errors import GarageError


def _vehicles_dir() -> Path | None:
    try:
        return locate.vehicles_dir()
    except GarageError:
        return None


VEHICLES = _vehicles_dir()


@pytest.fixture
def vehicles_present() -> None:
    """The real FlightGear vehicles: a test that needs them skips where the machine lacks them, and fails under
    `make test` or CI=true, which provision them (conftest.require), so a broken lookup cannot hide as a skip."""
    require("vehicles")


needs_vehicles = pytest.mark.usefixtures("vehicles_present")


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> VehicleLibrary:
    """One library over the real vehicles with its own cache, shared by the tests of this module."""
    require("vehicles")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("GARAGE_EXP_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield VehicleLibrary(VEHICLES)


def _polygon_triangles(path: Path) -> int:
    """Triangles a fan makes of the polygon surfaces, counted straight from the text."""
    text = path.read_text(encoding="latin-1")
    total = 0
    for flags, refs in re.findall(r"SURF (0x[0-9a-fA-F]+)\s+mat \d+\s+refs (\d+)", text):
        if int(flags, 16) & 0xF == 0 and int(refs) >= 3:
            total += int(refs) - 2
    return total


# --- AC3D reader on real files -------------------------------------------------------------------------

@needs_vehicles
@pytest.mark.parametrize("name, zero_area", [("tcamryred", 0), ("VWJetta_S1", 0), ("it_policecar1", 0),
                                             ("YellowContainerTruck", 41), ("hatchback_blue", 0)])
def test_reader_keeps_every_polygon_with_uvs(name, zero_area):
    path = VEHICLES / f"{name}.ac"
    ac = ac3d.read_ac(path)
    parts = ac3d.mesh_parts(ac)  # every LOD: the count must match the file's text
    faces = sum(len(p.faces) for p in parts)
    assert faces == _polygon_triangles(path) - zero_area > 100  # zero-area triangles are dropped
    for part in parts:
        assert part.uvs.shape == (len(part.vertices), 2)
        assert np.isfinite(part.uvs).all()
        assert part.faces.max() < len(part.vertices)
        np.testing.assert_allclose(np.linalg.norm(part.normals, axis=1), 1.0, atol=1e-6)
    textured = [p for p in parts if p.texture]
    assert textured and all((VEHICLES / p.texture).exists() for p in textured)
    uvs = np.concatenate([p.uvs for p in textured])
    assert np.ptp(uvs[:, 0]) > 0.1 and np.ptp(uvs[:, 1]) > 0.1  # real coordinates, not a default fill


@needs_vehicles
def test_reader_counts_on_a_known_file():
    ac = ac3d.read_ac(VEHICLES / "VWJetta_S1.ac")
    polys = [o for o, _ in ac.world.walk() if o.kind == "poly"]
    assert [len(o.vertices) for o in polys] == [124]
    assert [len(o.surfaces) for o in polys] == [124]
    assert polys[0].texture == "VWJetta_S11.png" and polys[0].crease == 45.0
    assert ac.materials[0].name == "def" and ac.materials[0].emis == (0.08, 0.08, 0.08)
    # Its `data 37` block spans two lines and must not swallow the next keyword.
    lod = next(o for o, _ in ac.world.walk() if o.lod_range == (0.0, 1000.0))
    assert lod.data == "lod_near=0.000000\nlod_far=1000.000000"


@needs_vehicles
def test_nearest_lod_drops_the_far_level_of_detail():
    ac = ac3d.read_ac(VEHICLES / "minibuswhite1.ac")
    ranges = sorted(g.lod_range for g in ac3d.lod_groups(ac.world))
    assert ranges == [(0.0, 1000.0), (1000.0, 4000.0)]
    near = ac3d.nearest_lod(ac.world)
    assert [g.lod_range for g in ac3d.lod_groups(near)] == [(0.0, 1000.0)]
    assert near.face_count() < ac.world.face_count()
    assert ac.world.face_count() == near.face_count() + ac3d.lod_groups(ac.world)[1].face_count()


@needs_vehicles
def test_truncated_kids_list_is_read_with_a_warning(caplog):
    ac = ac3d.read_ac(VEHICLES / "motorhome.ac")  # declares 4 kids, holds 1
    assert len(ac.world.kids) == 1 and ac.world.face_count() > 1000
    assert "declares 4 kids" in caplog.text


# --- AC3D reader on a file written here ----------------------------------------------------------------

SYNTHETIC = """AC3Db
MATERIAL "paint" rgb 1 0 0  amb 0.2 0.2 0.2  emis 0.1 0.1 0.1  spec 1 1 1  shi 32  trans 0
OBJECT world
kids 1
OBJECT group
name "moved"
loc 10 0 0
rot 0 -1 0 1 0 0 0 0 1
kids 1
OBJECT poly
name "quad"
data 5
a
b c
loc 0 1 0
texture "none.png"
texrep 2 2
texoff 0.5 0
crease {crease}
numvert 5
0 0 0
1 0 0
1 1 0
0 1 0
0 0 1
numsurf 3
SURF {flags}
mat 0
refs 4
0 0 0
1 1 0
2 1 1
3 0 1
SURF 0x12
mat 0
refs 2
0 0 0
4 0 0
SURF {flags}
mat 0
refs 3
0 0 0
3 0 1
4 1 0
kids 0
"""


def _write(tmp_path: Path, crease: float = 45.0, flags: str = "0x10") -> Path:
    path = tmp_path / "quad.ac"
    path.write_text(SYNTHETIC.format(crease=crease, flags=flags))
    return path


def test_transforms_texrep_and_triangulation(tmp_path):
    ac = ac3d.read_ac(_write(tmp_path))
    quad = next(o for o, _ in ac.world.walk() if o.name == "quad")
    assert quad.data == "a\nb c"
    [part] = ac3d.mesh_parts(ac)
    assert len(part.faces) == 3  # quad -> 2 triangles, the line is skipped, 1 triangle
    # Child loc (0,1,0), then the group's 90 degree turn about z and loc (10,0,0): (x,y,z) -> (10-y-1, x, z).
    expected = {(9.0, 0.0, 0.0), (9.0, 1.0, 0.0), (8.0, 1.0, 0.0), (8.0, 0.0, 0.0), (9.0, 0.0, 1.0)}
    assert {tuple(np.round(v, 6)) for v in part.vertices} == expected
    assert {tuple(np.round(uv, 6)) for uv in part.uvs} == {(0.5, 0.0), (2.5, 0.0), (2.5, 2.0), (0.5, 2.0)}


def test_crease_splits_normals_at_sharp_edges(tmp_path):
    # The quad (in z=0) and the triangle (in x=0 before the turn) meet at 90 degrees.
    sharp = ac3d.mesh_parts(ac3d.read_ac(_write(tmp_path, crease=45.0)))[0]
    smooth = ac3d.mesh_parts(ac3d.read_ac(_write(tmp_path, crease=120.0)))[0]
    flat = ac3d.mesh_parts(ac3d.read_ac(_write(tmp_path, crease=120.0, flags="0x00")))[0]
    axis_aligned = lambda n: np.isclose(np.abs(n).max(axis=1), 1.0).all()  # noqa: E731
    assert axis_aligned(sharp.normals) and axis_aligned(flat.normals)
    assert not axis_aligned(smooth.normals)  # the shared edge's corners lean halfway between the faces
    assert len(smooth.vertices) < len(sharp.vertices)


def test_reader_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.ac"
    bad.write_text("AC3Db\nOBJECT world\nkids 1\nOBJECT poly\nnumvert 2\n0 0 0\n0 zero 0\nkids 0\n")
    with pytest.raises(GarageError, match=r"bad\.ac:7: bad vertex line"):
        ac3d.read_ac(bad)
    (tmp_path / "no.ac").write_text("solid x\n")
    with pytest.raises(GarageError, match="not an AC3D file"):
        ac3d.read_ac(tmp_path / "no.ac")
    with pytest.raises(GarageError, match="cannot read"):
        ac3d.read_ac(tmp_path / "missing.ac")


def test_missing_texture_is_a_garage_error(tmp_path):
    ac = ac3d.read_ac(_write(tmp_path))
    with pytest.raises(GarageError, match="texture 'none.png'"):
        ac3d.to_scene(ac)


# --- conversion ----------------------------------------------------------------------------------------

def test_length_axis_goes_to_x(tmp_path):
    """A box 4 long in file z and one 4 long in file x both end up 4 long in x, 1 high in z, on the floor."""
    from PIL import Image

    Image.new("RGB", (4, 4), (200, 30, 30)).save(tmp_path / "none.png")
    for name, size, look in (("along_z", (1.8, 1.0, 4.0), "emis 0.5 0.5 0.5 spec 1 1 1 shi 32 trans 0"),
                             ("along_x", (4.0, 1.0, 1.8), "emis 0 0 0 spec 1 1 1 shi 32 trans 0.3")):
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)]) * size + [3, 2, 1]
        faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
        lines = ["AC3Db", f'MATERIAL "m" rgb 1 1 1 amb 1 1 1 {look}',
                 "OBJECT world", "kids 1", "OBJECT poly", 'texture "none.png"', f"numvert {len(corners)}"]
        lines += [" ".join(map(str, c)) for c in corners] + [f"numsurf {len(faces)}"]
        for face in faces:
            lines += ["SURF 0x10", "mat 0", "refs 4"] + [f"{i} 0 0" for i in face]
        (tmp_path / f"{name}.ac").write_text("\n".join(lines + ["kids 0", ""]))
        conv = vehicles.convert(tmp_path / f"{name}.ac")
        np.testing.assert_allclose(conv.extents, [4.0, 1.8, 1.0], atol=1e-9)
        glb = vehicles.write_glb(conv, tmp_path / f"{name}.glb")
        import trimesh

        scene = trimesh.load(glb)
        np.testing.assert_allclose(scene.bounds, [[-2.0, -0.9, 0.0], [2.0, 0.9, 1.0]], atol=1e-6)
        [mesh] = scene.geometry.values()
        assert mesh.visual.material.emissiveFactor is None or not np.any(mesh.visual.material.emissiveFactor)
        assert mesh.visual.material.baseColorFactor[3] == 255  # trans 0.3 dropped: fully opaque
        assert mesh.visual.material.roughnessFactor > 0.5  # spec 1 toned down to 0.2: not a mirror


@needs_vehicles
@pytest.mark.parametrize("name", ["tcamryred", "hatchback_red", "minibuswhite1"])
def test_converted_glb_is_centred_on_the_floor_and_textured(library, name):
    import trimesh

    model = library.get(name)
    scene = trimesh.load(model.glb)
    (x0, y0, z0), (x1, y1, z1) = scene.bounds
    assert z0 == pytest.approx(0.0, abs=1e-4)
    assert x0 == pytest.approx(-x1, abs=1e-4) and y0 == pytest.approx(-y1, abs=1e-4)
    assert (x1 - x0, y1 - y0, z1 - z0) == pytest.approx((model.length, model.width, model.height), abs=1e-3)
    assert model.length > model.width
    for mesh in scene.geometry.values():
        mat = mesh.visual.material
        assert mesh.visual.uv is not None and len(mesh.visual.uv) == len(mesh.vertices)
        assert mat.baseColorTexture is not None and mat.baseColorTexture.size[0] >= 64
        assert mat.emissiveFactor is None or not np.any(mat.emissiveFactor)


@needs_vehicles
def test_converted_model_drops_its_far_lod(library):
    model = library.get("pickupred1")
    conv = vehicles.convert(model.source)
    ac = ac3d.read_ac(model.source)
    assert sum(len(p.faces) for p in conv.parts) == ac3d.nearest_lod(ac.world).face_count() < ac.world.face_count()


def _placed(conv) -> np.ndarray:
    points = np.concatenate([p.vertices for p in conv.parts])
    return points @ conv.transform[:3, :3].T + conv.transform[:3, 3]


@needs_vehicles
@pytest.mark.parametrize("name", ["hatchback_red", "van_red", "motorhome", "minibuswhite1", "boxtruckusps",
                                  "tcamryred", "gr_paramedic1"])
def test_nose_points_to_plus_x(name):
    """A bonnet is lower than a tailgate, boot or box: the front tenth of the length is the lower end.
    (The nose directions were first decided by looking at rendered side views; this keeps them.)"""
    conv = vehicles.convert(VEHICLES / f"{name}.ac")
    points, half = _placed(conv), conv.extents[0] / 2
    front = points[points[:, 0] > 0.8 * half, 2].max()
    rear = points[points[:, 0] < -0.8 * half, 2].max()
    assert front < rear - 0.1


@needs_vehicles
def test_headlights_end_up_in_front():
    conv = vehicles.convert(VEHICLES / "honda1.ac")
    ac = ac3d.read_ac(VEHICLES / "honda1.ac")
    lights = {o.name: [] for o, _ in ac.world.walk() if o.kind == "light"}
    for obj, matrix in ac.world.walk():
        if obj.kind == "light":
            lights[obj.name].append((conv.transform[:3, :3] @ matrix[:3, 3] + conv.transform[:3, 3])[0])
    assert min(lights["headlight"]) > 1.5 and max(lights["taillight"]) < -1.5


# --- classification ------------------------------------------------------------------------------------

def test_names_give_kind_and_colour():
    assert [vehicles.kind_of(n) for n in ("tcamryred", "hondacrvblack", "dodgeramred", "pickupred1", "van_silver",
                                          "minibuswhite1", "bus-muc", "tourbus1", "boxtruckusps", "motorhome")] \
        == ["car", "suv", "pickup", "pickup", "van", "van", "bus", "bus", "truck", "van"]
    assert vehicles.colour_from_name("pickupyelwhite") == "yellow"
    assert vehicles.colour_from_name("camaroblack") == "black"
    assert vehicles.colour_from_name("VWJetta_S1") is None


def test_size_class_thresholds():
    assert vehicles.size_class_of(4.39, 1.5) == "small"
    assert vehicles.size_class_of(4.4, 1.5) == "medium"
    assert vehicles.size_class_of(5.0, 1.89) == "medium"
    assert vehicles.size_class_of(4.6, 2.2) == "large"  # minibus: medium length, too tall
    assert vehicles.size_class_of(5.4, 1.5) == "large"


def test_colour_words_of_plain_colours():
    rgb = np.array([[0.05, 0.05, 0.05], [0.9, 0.9, 0.92], [0.45, 0.45, 0.45], [0.8, 0.1, 0.1],
                    [0.1, 0.2, 0.8], [0.1, 0.6, 0.1], [0.8, 0.7, 0.1], [0.6, 0.1, 0.6]])
    assert list(vehicles.colour_words(rgb)) == ["black", "white", "silver", "red", "blue", "green", "yellow",
                                                "other"]
    assert vehicles.dominant_colour({"black": 0.5, "red": 0.3, "silver": 0.2}) == "red"
    assert vehicles.dominant_colour({"black": 0.8, "silver": 0.2}) == "black"


@needs_vehicles
def test_library_classes_are_plausible(library):
    names = [m.name for m in library.models]
    assert names == sorted(names) and len(names) >= 40
    for m in library.models:
        assert 3.0 <= m.length <= 13.0 and 1.4 <= m.width <= 2.7 and 1.1 <= m.height <= 4.2, m
        assert m.size_class in vehicles.SIZE_CLASSES and m.colour in vehicles.COLOURS and m.kind in vehicles.KINDS
    get = library.get
    assert (get("hatchback_red").size_class, get("tcamryred").size_class, get("dodgeramred").size_class) \
        == ("small", "medium", "large")
    assert get("tcamrysilver").colour == "silver" and get("mazda_wagontaxi").colour == "yellow"
    assert get("tourbus1").kind == "bus" and not get("tourbus1").fits(2.8) and get("tcamryred").fits(2.8)
    assert "YellowContainerTruck" in library.excluded  # 2.7+ m wide: not a plausible garage vehicle
    with pytest.raises(GarageError, match="excluded"):
        get("YellowContainerTruck")
    with pytest.raises(GarageError, match="unknown vehicle model 'nope'"):
        get("nope")


# --- choose --------------------------------------------------------------------------------------------

@needs_vehicles
def test_choose_is_deterministic_and_filters(library):
    picks = [library.choose(size_class="medium", rng=np.random.default_rng(7)).name for _ in range(3)]
    assert len(set(picks)) == 1
    seq_a = [library.choose(rng=rng).name for rng in [np.random.default_rng(1)] for _ in range(10)]
    seq_b = [library.choose(rng=rng).name for rng in [np.random.default_rng(1)] for _ in range(10)]
    assert seq_a == seq_b and len(set(seq_a)) > 1
    for seed in range(10):
        m = library.choose(size_class="large", colour="white", max_height=2.7, rng=np.random.default_rng(seed))
        assert m.size_class == "large" and m.colour == "white" and m.height <= 2.7
    assert library.choose(kind="suv", colour="red").name == "hondacrvred"
    assert library.choose().name == library.choose().name  # no rng: a fixed seed


@needs_vehicles
def test_choose_errors_name_the_filter(library):
    with pytest.raises(GarageError, match=r"no vehicle model matches size_class=small, kind=bus"):
        library.choose(size_class="small", kind="bus")
    with pytest.raises(GarageError, match="unknown colour 'mauve'"):
        library.choose(colour="mauve")


# --- cache ---------------------------------------------------------------------------------------------

@needs_vehicles
def test_conversion_is_lazy_and_reused(tmp_path, monkeypatch):
    monkeypatch.setenv("GARAGE_EXP_CACHE", str(tmp_path))
    root = tmp_path / "src"
    root.mkdir()
    for name in ("hatchback_red.ac", "hatchback_red.png", "tcamryblue.ac", "tcamryblue1.png"):
        shutil.copy(VEHICLES / name, root / name)
    first = VehicleLibrary(root)
    assert not list((tmp_path / "vehicles").glob("*.glb"))  # nothing converted until used
    glb = Path(first.get("hatchback_red").glb)
    assert glb.exists() and glb.name.startswith("hatchback_red-")
    assert [p.name for p in (tmp_path / "vehicles").glob("*.glb")] == [glb.name]
    meta = json.loads((tmp_path / "vehicles" / "metadata.json").read_text())
    assert set(meta) == {"hatchback_red", "tcamryblue"}

    def refuse(*args, **kwargs):
        raise AssertionError("reconverted")

    monkeypatch.setattr(vehicles, "convert", refuse)
    monkeypatch.setattr(vehicles, "_metadata", refuse)
    second = VehicleLibrary(root)
    assert second.get("hatchback_red").glb == str(glb)
    assert second.get("hatchback_red").length == first.get("hatchback_red").length
    # An edited .ac has a new hash: converted again under a new name.
    (root / "hatchback_red.ac").write_text((root / "hatchback_red.ac").read_text() + "\n")
    with pytest.raises(AssertionError, match="reconverted"):
        VehicleLibrary(root)


# --- locate --------------------------------------------------------------------------------------------

def test_locate_order_and_errors(tmp_path, monkeypatch):
    monkeypatch.setattr(paths, "shared_dir", lambda: tmp_path / "shared")
    monkeypatch.setenv("GARAGE_EXP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(locate.ASSETS_ENV, raising=False)
    monkeypatch.delenv(locate.MODELS_ENV, raising=False)
    with pytest.raises(GarageError, match="python -m garage_exp.assets fetch"):
        locate.vehicles_dir()
    with pytest.raises(GarageError, match=locate.MODELS_ENV):
        locate.models_dir()

    fetched = tmp_path / "cache" / "flightgear"
    fetched.mkdir(parents=True)
    (fetched / "a.ac").write_text("AC3Db\n")
    assert locate.vehicles_dir() == fetched
    shared = tmp_path / "shared" / "assets" / "vehicles" / "flightgear"
    shared.mkdir(parents=True)
    (shared / "b.ac").write_text("AC3Db\n")
    assert locate.vehicles_dir() == shared
    monkeypatch.setenv(locate.ASSETS_ENV, str(tmp_path / "cache"))  # holds no vehicles/flightgear nor .ac
    with pytest.raises(GarageError, match=locate.ASSETS_ENV):
        locate.vehicles_dir()
    monkeypatch.setenv(locate.ASSETS_ENV, str(fetched))
    assert locate.vehicles_dir() == fetched

    (tmp_path / "cache" / "models").mkdir()
    (tmp_path / "cache" / "models" / "yolo11n.pt").write_bytes(b"x")
    assert locate.models_dir() == tmp_path / "cache" / "models"
    (tmp_path / "shared" / "models" / "yolo11n_int8_openvino_model").mkdir(parents=True)
    assert locate.models_dir() == tmp_path / "shared" / "models"
    monkeypatch.setenv(locate.MODELS_ENV, str(tmp_path / "nowhere"))
    with pytest.raises(GarageError, match="is not a folder"):
        locate.models_dir()


@pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="dpkg-deb is not installed")
def test_extract_transport_from_a_package(tmp_path):
    """The fetch's unpacking step on a small package built here (the real one is too big for a test)."""
    pkg = tmp_path / "pkg"
    transport = pkg / locate.TRANSPORT_DIR
    transport.mkdir(parents=True)
    (transport / "car.ac").write_text("AC3Db\n")
    (transport / "car.png").write_bytes(b"png")
    (transport / "car.xml").write_text("<x/>")  # not copied: only .ac and .png
    (transport / "sub").mkdir()
    (transport / "sub" / "deep.ac").write_text("AC3Db\n")  # not copied: only the folder itself
    (pkg / locate.COPYRIGHT_FILE).parent.mkdir(parents=True)
    (pkg / locate.COPYRIGHT_FILE).write_text("GPL-2+\n")
    (pkg / "DEBIAN").mkdir()
    (pkg / "DEBIAN" / "control").write_text("Package: fake\nVersion: 1\nArchitecture: all\n"
                                            "Maintainer: t <t@t>\nDescription: t\n")
    deb = tmp_path / "fake.deb"
    subprocess.run(["dpkg-deb", "--build", "-Zgzip", str(pkg), str(deb)], check=True, capture_output=True)
    dest = tmp_path / "out"
    assert locate.extract_transport(deb, dest) == 2
    assert sorted(p.name for p in dest.iterdir()) == ["COPYRIGHT.debian", "car.ac", "car.png"]
    (tmp_path / "broken.deb").write_bytes(b"not a deb")
    with pytest.raises(GarageError):
        locate.extract_transport(tmp_path / "broken.deb", tmp_path / "out2")


@needs_vehicles
def test_where_command_prints_the_folders():
    proc = subprocess.run([sys.executable, "-m", "garage_exp.assets", "where"], capture_output=True, text=True,
                          timeout=60)
    assert f"vehicles: {VEHICLES}" in proc.stdout


@needs_vehicles
def test_excluded_vehicles_are_not_a_warning_on_every_command(caplog):
    """Three implausible models were warned about by every command; they are said once at set-up (`ensure`)
    and at debug level otherwise (issue 31, item 12)."""
    import logging

    caplog.set_level(logging.WARNING)
    getattr(vehicles, "_WARNED", set()).clear()
    library = VehicleLibrary(VEHICLES)
    assert library.excluded
    assert not [r for r in caplog.records if "excluded" in r.getMessage()]
