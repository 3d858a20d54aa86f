"""Pinned numbers of every lens (issue 48, item 1): projections, rays and K of the pinhole, the fisheye
(Kannala-Brandt) and the cylindrical lens, the camera rotation, the detector's view of each, a frame's projection
and a box's truncation, recorded from the code before the lenses moved into one place (values are literals
computed then), so the move is shown to keep every number."""

from __future__ import annotations

import dataclasses

import numpy as np

from garage_exp.perception.detect.base import DEFAULT_CAMERA
from garage_exp.perception.groundtruth import projected_truncation
from garage_exp.render.base import Frame
from garage_exp.render.fisheye import face_rotation, view_remap
from garage_exp.scene.camera import camera_to_world
from garage_exp.scene.description import CameraSpec, Pose
from garage_exp.scene.lenses import Cylindrical, Fisheye, Pinhole, lens_of
from garage_exp.scene.views import picture_lens

NAN = float("nan")
D = np.array([[1.0, 0.0, 0.0], [0.8, 0.3, -0.2], [0.2, -0.9, 0.4], [-0.3, 0.5, 0.6], [0.6, 0.0, -1.0]])
L = np.array([[4.0, 0.5, -0.3], [2.0, -1.0, 0.8], [-1.0, 0.2, 0.1]])
PIX = [(0, 0), (37, 11), (80, 60), (159, 119), (3, 60)]  # (column, row)
KB = (-0.0417, 0.0005, 0.0, 0.0)
SPEC = CameraSpec("front", Pose(1.0, 2.0, 1.2, 30.0), pitch=12.0, fovy=70.0, width=320, height=240)
FISHEYE_SPEC = CameraSpec("f", Pose(), width=160, height=120, model="fisheye", fov=190.0, k=KB)
EGO = Pose(3.0, -1.0, 0.0, -20.0)
WORLD = np.array([[8.0, -2.0, 1.0], [5.0, 0.5, 0.2], [1.0, -1.0, 1.0]])
BOX = np.array([[x, y, z] for x in (6.0, 8.0) for y in (-3.0, -1.0) for z in (0.0, 1.5)])

FISHEYE_K = [[54.264974337481, 0.0, 79.5], [0.0, 54.264974337481, 59.5], [0.0, 0.0, 1.0]]
FISHEYE_F = 54.264974337481
FISHEYE_PROJECT = [[80.0, 60.0], [61.024227300834, 72.650515132778], [142.755396788895, 32.108712538269], [22.232207963338, -9.321350443994], [80.0, 113.469492062091]]
FISHEYE_RAYS = [[-0.087155742748, 0.797557284384, 0.596913942401], [0.293753396943, 0.629976739905, 0.718914632598], [0.999915101345, -0.009213851043, -0.009213851043], [-0.087155742748, -0.797557284384, -0.596913942401], [0.005905099754, 0.999961206497, -0.00653569416]]
FISHEYE_INSIDE = [False, True, True, False, True]
FISHEYE_UNDISTORT = [0.100041747237, 0.715159067322, 1.415402891018]
PINHOLE_VIEW = [46.18802153517, 46.18802153517, 80.0, 60.0]
PINHOLE_PROJECT = [[80.0, 60.0], [62.679491924311, 71.547005383793], [287.846096908265, -32.37604307034], [NAN, NAN], [80.0, 136.98003589195]]
PINHOLE_RAYS = [[0.421745400419, 0.7259189335, 0.543297818154], [0.582291907773, 0.535797058584, 0.611438996266], [0.999882833095, -0.010824049178, -0.010824049178], [0.421745400419, -0.7259189335, -0.543297818154], [0.516855614847, 0.856054301995, -0.005595126157]]
CYL_VIEW = [50.929581789407, 50.929581789407, 80.0, 60.0]
CYL_PROJECT = [[80.0, 60.0], [61.727959804815, 71.921713357703], [148.86328203631, 37.903645011823], [-27.523339139621, 7.593892687303], [80.0, 144.882636315678]]
CYL_RAYS = [[0.006383936854, 0.650241576749, 0.75970068923], [0.486322120727, 0.53657377366, 0.689622636165], [0.999903623337, -0.009816846261, -0.009817003958], [0.006383936854, -0.650241576749, -0.75970068923], [0.068664949902, 0.997591475048, -0.009817003958]]
PINHOLE_SPEC = [171.377760809054, 171.377760809054, 160.0, 120.0]
PINHOLE_TO_PIXELS = [[138.577779898868, 132.853332060679], [245.688880404527, 51.448895676378], [194.275552161811, 137.137776080905]]
CAMERA_TO_WORLD = [[0.963287340793, -0.173648177667, 0.204753045059, 4.623732907437], [0.169853548357, 0.984807753012, 0.036103486226, 0.537365098246], [-0.207911690818, 0.0, 0.978147600734, 1.2], [0.0, 0.0, 0.0, 1.0]]
FACE_FRONT = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
FACE_LEFT = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
FACE_RIGHT = [[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
FACE_UP = [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]]
FACE_DOWN = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
FACE_BACK = [[-1.0, -0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, 1.0]]
INTRINSICS_RAW = (160, 120, 54.264974337481235, 54.264974337481235, 80.0, 60.0, 'fisheye', (-0.0417, 0.0005, 0.0, 0.0), 190.0)
MATRIX_RAW = [[54.264974337481, 0.0, 80.0], [0.0, 54.264974337481, 60.0], [0.0, 0.0, 1.0]]
INTRINSICS_PERSPECTIVE = (160, 120, 46.18802153517007, 46.18802153517007, 80.0, 60.0, 'pinhole', (0.0, 0.0, 0.0, 0.0), 0.0)
MATRIX_PERSPECTIVE = [[46.18802153517, 0.0, 80.0], [0.0, 46.18802153517, 60.0], [0.0, 0.0, 1.0]]
INTRINSICS_CYLINDRICAL = (160, 120, 50.92958178940651, 50.92958178940651, 80.0, 60.0, 'cylindrical', (0.0, 0.0, 0.0, 0.0), 0.0)
MATRIX_CYLINDRICAL = [[50.929581789407, 0.0, 80.0], [0.0, 50.929581789407, 60.0], [0.0, 0.0, 1.0]]
INTRINSICS_PINHOLE = (320, 240, 171.37776080905377, 171.37776080905377, 160.0, 120.0, 'pinhole', (0.0, 0.0, 0.0, 0.0), 0.0)
INTRINSICS_DEFAULT = (640, 480, 415.69219381653056, 415.69219381653056, 320.0, 240.0, 'pinhole')
REMAP_SUMS = [1526399.9997138977, 1142399.9999530315, 184310400.0]
FRAME_PINHOLE = [[344.677863312826, 95.812246549019, 2.862917222151], [191.034019965999, 394.21210496952, 0.564018423319], [119.132775304346, 74.128053735721, -3.710240615042]]
TRUNC_PINHOLE = 0.954111745186
FRAME_FISHEYE = [[246.4743341977, 108.674225281301, 2.862917222151], [171.863139861687, 224.820985376214, 0.564018423319], [321.950334265288, 301.783252624183, -3.710240615042]]
TRUNC_FISHEYE = 0.0


def same(got, want) -> None:
    got = np.asarray(got, dtype=float)
    assert got.shape == np.shape(want)
    assert np.allclose(got, np.asarray(want, dtype=float), rtol=0.0, atol=1e-9, equal_nan=True), got.tolist()


def uv(pair) -> np.ndarray:
    return np.stack(pair, axis=1)


def test_the_fisheye_lens_keeps_its_numbers():
    lens = Fisheye(160, 120, 190.0, KB)
    same(lens.K - np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]]), FISHEYE_K)  # OpenCV's pixel centres
    same(lens.f, FISHEYE_F)
    same(uv(lens.project(D)), FISHEYE_PROJECT)
    rays, inside = lens.rays()
    same([rays[r, c] for c, r in PIX], FISHEYE_RAYS)
    assert [bool(inside[r, c]) for c, r in PIX] == FISHEYE_INSIDE
    same(lens.undistort(np.array([0.1, 0.7, 1.3])), FISHEYE_UNDISTORT)


def test_the_pinhole_and_cylindrical_lenses_keep_their_numbers():
    pinhole = Pinhole.from_fovx(160, 120, 120.0)
    same([pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy], PINHOLE_VIEW)
    same(uv(pinhole.project(D)), PINHOLE_PROJECT)
    same([pinhole.rays()[0][r, c] for c, r in PIX], PINHOLE_RAYS)
    cylindrical = Cylindrical.from_fovx(160, 120, 180.0)
    same([cylindrical.fx, cylindrical.fy, cylindrical.cx, cylindrical.cy], CYL_VIEW)
    same(uv(cylindrical.project(D)), CYL_PROJECT)
    same([cylindrical.rays()[0][r, c] for c, r in PIX], CYL_RAYS)
    own = lens_of(SPEC)
    same([own.fx, own.fy, own.cx, own.cy], PINHOLE_SPEC)
    same(uv(own.pixels(L)), PINHOLE_TO_PIXELS)
    mx, my, flat = view_remap(Fisheye(160, 120, 190.0, KB), Cylindrical.from_fovx(160, 120, 180.0))
    same([mx.astype(float).sum(), my.astype(float).sum(), flat.sum()], REMAP_SUMS)


def test_the_camera_rotation_keeps_its_numbers():
    same(camera_to_world(EGO, SPEC), CAMERA_TO_WORLD)
    for face, want in (("front", FACE_FRONT), ("left", FACE_LEFT), ("right", FACE_RIGHT), ("up", FACE_UP),
                       ("down", FACE_DOWN), ("back", FACE_BACK)):
        same(face_rotation(face), want)


def test_the_detector_sees_the_same_camera():
    for view, want, matrix in (("raw", INTRINSICS_RAW, MATRIX_RAW),
                               ("perspective", INTRINSICS_PERSPECTIVE, MATRIX_PERSPECTIVE),
                               ("cylindrical", INTRINSICS_CYLINDRICAL, MATRIX_CYLINDRICAL)):
        cam = picture_lens(dataclasses.replace(FISHEYE_SPEC, view=view))
        assert (cam.width, cam.height, cam.model) == (want[0], want[1], want[6])
        same([cam.fx, cam.fy, cam.cx, cam.cy], want[2:6])
        same(cam.K, matrix)
        same(cam.matrix, matrix)  # the name users' callable: detectors read before
        if view == "raw":
            assert tuple(cam.k) == want[7] and cam.fov == want[8]
    cam = picture_lens(SPEC)
    assert (cam.width, cam.height, cam.model) == (320, 240, "pinhole")
    same([cam.fx, cam.fy, cam.cx, cam.cy], INTRINSICS_PINHOLE[2:6])
    cam = DEFAULT_CAMERA
    assert (cam.width, cam.height, cam.model) == (640, 480, "pinhole")
    same([cam.fx, cam.fy, cam.cx, cam.cy], INTRINSICS_DEFAULT[2:6])


def test_frames_project_and_truncate_as_before():
    ids = np.zeros((240, 320), np.int32)
    pose = camera_to_world(EGO, SPEC)
    frame = Frame("front", np.zeros((240, 320, 3), np.uint8), ids, pose, lens_of(SPEC))
    pixels, depth = frame.project(WORLD)
    same(np.c_[pixels, depth], FRAME_PINHOLE)  # a point behind the camera mirrors through, as before
    same(projected_truncation(frame, BOX), TRUNC_PINHOLE)
    lens = lens_of(dataclasses.replace(FISHEYE_SPEC, width=320, height=240))
    frame = Frame("front", np.zeros((240, 320, 3), np.uint8), ids, pose, lens)
    pixels, depth = frame.project(WORLD)
    same(np.c_[pixels, depth], FRAME_FISHEYE)
    same(projected_truncation(frame, BOX), TRUNC_FISHEYE)
