"""Per-actor ground truth of one rendered frame: visibility, 2D boxes, distance, truncation, KITTI level.

An actor is a vehicle or a person: both go by their entity's extent (a person's box: its length along +x, where
it faces, its shoulder width and its height, feet at z=0), so everything below holds for people too.

Inputs are plain arrays (no SAPIEN): the frame's id picture, each vehicle's unoccluded silhouette (the vehicle
rendered with everything else hidden) and the scene description for roles and extents.

Boxes are (x1, y1, x2, y2) pixel edges: a box around columns 10..19 is x1=10, x2=20, so x2 - x1 is the width in
pixels. `full_box` bounds the unoccluded silhouette (within the image), `visible_box` the visible pixels.

Truncation is geometric: the vehicle's 3D box (its extent, centred on its pose, wheels at z=0) is clipped at the
camera's near plane and projected with the frame's intrinsics; truncation is the share of that projected
rectangle's area that lies outside the image. Only a vehicle without an extent (and no Box shapes to take one
from) falls back to the silhouette: 1.0 when it touches the image border, else 0.0.

KITTI difficulty (Geiger et al., 2012) uses the full box height, an occlusion state and the truncation. KITTI's
occlusion states are annotators' judgements; here they come from the visible fraction (visible / unoccluded
pixels): fully visible >= 0.85, partly occluded >= 0.5, largely occluded > 0, fully occluded = 0.
- easy: height >= 40 px, fully visible, truncation <= 0.15
- moderate: height >= 25 px, at most partly occluded, truncation <= 0.30
- hard: height >= 25 px, at most largely occluded, truncation <= 0.50
- otherwise "ignored" (a fully occluded vehicle is always ignored).

What hides an actor (`occluder`): the category of whatever covers the largest share of its hidden pixels (its
unoccluded silhouette inside the image minus its visible pixels), read from the frame's id picture: `pillar`
(the structure's pillars, `Frame.pillars`), `vehicle` (any other car: parked, moving, the case's occluder car,
the ego), `person`, `structure` (every other drawn thing: walls, ceiling, beams, obstacle blocks, ramps, lamps,
clutter, a box occluder), or `none` when fewer than MIN_HIDDEN of its silhouette is hidden (a part outside the
image is truncation, not hiding: the silhouette stops at the border). Pixels where nothing is drawn (id 0) and
floor decals hide nothing. On a tie the earlier category of OCCLUDERS wins.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from garage_exp.core import arrays
from garage_exp.render import Frame
from garage_exp.scene.camera import to_camera
from garage_exp.scene.description import VEHICLE_ROLES, Box, Entity, Pose, Scene

BoxXYXY = tuple[int, int, int, int]
Kitti = Literal["easy", "moderate", "hard", "ignored"]

FULLY_VISIBLE = 0.85
PARTLY_OCCLUDED = 0.5
# (min full-box height in px, worst occlusion state allowed, max truncation) per level, easiest first.
KITTI_LEVELS: tuple[tuple[str, int, int, float], ...] = (
    ("easy", 40, 0, 0.15),
    ("moderate", 25, 1, 0.30),
    ("hard", 25, 2, 0.50),
)
OCCLUSION_NAMES = ("fully_visible", "partly_occluded", "largely_occluded", "fully_occluded")
# What may hide an actor (see the module doc), in the order that breaks ties; `structure` is every other drawn id.
OCCLUDERS = ("pillar", "vehicle", "person", "structure")
NO_OCCLUDER = "none"
MIN_HIDDEN = 0.02  # hidden pixels under this share of the silhouette: nothing hides the actor


@dataclass(frozen=True)
class VehicleTruth:
    name: str
    role: str
    visible_pixels: int
    unoccluded_pixels: int
    visible_fraction: float
    visible_box: BoxXYXY | None  # None when no pixel of the vehicle is visible
    full_box: BoxXYXY
    distance: float  # camera centre to the vehicle's 3D box centre, metres
    truncation: float  # 0..1, see the module doc
    occlusion: int  # KITTI occlusion state 0..3 (OCCLUSION_NAMES)
    kitti: Kitti
    kind: str = "vehicle"  # "vehicle" | "person" (the record is the same for both)
    off_axis: float = float("nan")  # degrees between the optical axis and the ray to the 3D box's centre
    occluder: str = NO_OCCLUDER  # what hides most of it: OCCLUDERS or "none" (see the module doc)
    height: float = float("nan")  # its 3D box's height (m): a child or a crouching adult, a car or a van
    light: float = float("nan")  # the lamps' direct light at its centre (`direct_light`)
    camera_height: float = float("nan")  # the camera centre's height above the floor (m) when it took the frame

    @property
    def box_height(self) -> int:
        return self.full_box[3] - self.full_box[1]


def occlusion_state(visible_fraction: float) -> int:
    if visible_fraction >= FULLY_VISIBLE:
        return 0
    if visible_fraction >= PARTLY_OCCLUDED:
        return 1
    if visible_fraction > 0:
        return 2
    return 3


def kitti_level(box_height: float, visible_fraction: float, truncation: float) -> Kitti:
    occ = occlusion_state(visible_fraction)
    if occ == 3:
        return "ignored"
    for name, min_height, worst_occlusion, max_truncation in KITTI_LEVELS:
        if box_height >= min_height and occ <= worst_occlusion and truncation <= max_truncation:
            return name  # type: ignore[return-value]
    return "ignored"


def occluder_category(hidden_by: Sequence[int], unoccluded_pixels: int) -> str:
    """The category (OCCLUDERS) holding most of an actor's hidden pixels (`hidden_by`: a count per category), or
    "none" when they are fewer than MIN_HIDDEN of its silhouette."""
    hidden = sum(hidden_by)
    if not hidden or hidden < MIN_HIDDEN * unoccluded_pixels:
        return NO_OCCLUDER
    return OCCLUDERS[max(range(len(hidden_by)), key=lambda k: (hidden_by[k], -k))]


def occluder_ids(frame: Frame, scene: Scene, ids: Mapping[str, int]) -> dict[str, list[int]]:
    """The ids of each named category but `structure` (every other drawn id): pillars (`frame.pillars`, and a
    pillar with its own id), vehicles and people (the entities of `ids`, name -> id, by their scene entity)."""
    entities = {e.name: e for e in scene.entities}
    out: dict[str, set[int]] = {"pillar": set(frame.pillars), "vehicle": set(), "person": set()}
    for name, i in ids.items():
        entity = entities.get(name)
        if entity is None:
            continue
        if entity.is_pillar:
            out["pillar"].add(int(i))
        elif entity.is_person:
            out["person"].add(int(i))
        elif entity.role in VEHICLE_ROLES and entity.kind != "box":  # a box occluder is structure
            out["vehicle"].add(int(i))
    return {k: sorted(v) for k, v in out.items()}


def mask_box(mask) -> BoxXYXY | None:
    """Tight box (pixel edges) of a boolean mask, or None when it is empty (`mask_boxes` of one mask)."""
    box, empty = mask_boxes(mask)
    return None if bool(empty) else tuple(int(v) for v in box.tolist())


def local_box(entity: Entity) -> tuple[np.ndarray, np.ndarray] | None:
    """The vehicle's 3D box in its own frame (lo, hi): its extent centred on x=y=0 with wheels at z=0, else the
    union of its Box shapes, else None."""
    if entity.extent is not None:
        length, width, height = entity.extent
        return np.array([-length / 2, -width / 2, 0.0]), np.array([length / 2, width / 2, height])
    boxes = [s for s in entity.shapes if isinstance(s, Box)]
    if not boxes:
        return None
    los, his = [], []
    for b in boxes:
        corners = _corners(-np.asarray(b.size) / 2, np.asarray(b.size) / 2)
        placed = _place(corners, b.offset)
        los.append(placed.min(axis=0))
        his.append(placed.max(axis=0))
    return np.min(los, axis=0), np.max(his, axis=0)


def world_corners(entity: Entity, pose: Pose) -> np.ndarray | None:
    """The 8 world corners of the vehicle's 3D box at `pose`."""
    box = local_box(entity)
    if box is None:
        return None
    return _place(_corners(*box), pose)


def projected_truncation(frame: Frame, corners: np.ndarray, near: float = 0.05) -> float:
    """Share of the projected 3D box's rectangle outside the image (1.0 when it is behind the camera). A fisheye
    (or cylindrical) frame bends the box's edges: points along them are projected through its lens, with no
    near plane (a 190-degree lens sees behind its own plane); a perspective frame's box is clipped at the near
    plane."""
    if not frame.lens.perspective:
        points = _edge_points(to_camera(frame.cam_to_world, corners))
        u, v = frame.lens.project(points)
        ok = np.isfinite(u) & np.isfinite(v)
        if not ok.any():
            return 1.0
        return _outside(u[ok], v[ok], frame.width, frame.height)
    points = _clip_near(to_camera(frame.cam_to_world, corners), near)
    if len(points) == 0:
        return 1.0
    u, v = frame.lens.pixels(points)
    return _outside(u, v, frame.width, frame.height)


def _outside(u: np.ndarray, v: np.ndarray, width: int, height: int) -> float:
    """Share of the rectangle around the points (u, v) that lies outside a width x height image."""
    area = (u.max() - u.min()) * (v.max() - v.min())
    if area <= 0:
        return 1.0
    iw = max(0.0, min(u.max(), width) - max(u.min(), 0.0))
    ih = max(0.0, min(v.max(), height) - max(v.min(), 0.0))
    return float(np.clip(1.0 - iw * ih / area, 0.0, 1.0))


def _edge_points(local: np.ndarray, per_edge: int = 9) -> np.ndarray:
    """Points along the 12 edges of a box given by its 8 corners (camera frame), ends included."""
    t = np.linspace(0.0, 1.0, per_edge)[:, None]
    return np.concatenate([local[a] + t * (local[b] - local[a]) for a, b in _EDGES], axis=0)


@dataclass(frozen=True)
class MaskStats:
    """The pixel work of one actor's ground truth: its unoccluded silhouette and visible pixels, counted and
    boxed (None: empty), whether the silhouette touches the image border, and its hidden pixels per category of
    OCCLUDERS (empty: not counted) (`batch_mask_stats`, `stats_of`); `truth_records` turns them into records."""

    name: str
    unoccluded_pixels: int
    visible_pixels: int
    full_box: BoxXYXY | None
    visible_box: BoxXYXY | None
    touches_border: bool
    hidden_by: tuple[int, ...] = ()


def mask_boxes(masks):
    """Tight boxes (pixel edges x1, y1, x2, y2, as `mask_box`) of (..., H, W) bool masks, numpy or torch: (...,
    4) integer boxes and (...) bool `empty` (whose boxes are meaningless)."""
    h, w = masks.shape[-2:]
    rows, cols = masks.any(axis=-1), masks.any(axis=-2)  # (..., H), (..., W)
    # argmax gives the first maximal index: the first row (column) holding a pixel, from either end.
    y1, x1 = (rows * 1).argmax(axis=-1), (cols * 1).argmax(axis=-1)
    y2 = h - (arrays.flip(rows, -1) * 1).argmax(axis=-1)
    x2 = w - (arrays.flip(cols, -1) * 1).argmax(axis=-1)
    return arrays.xp(masks).stack([x1, y1, x2, y2], axis=-1), ~rows.any(axis=-1)


def batch_mask_stats(ids, silhouettes, actor_ids, see_through=(), occluders: Mapping | None = None) -> dict:
    """The pixel statistics of K actors in each of N frames, numpy or torch (on the pictures' device).

    ids: (N, H, W) integer entity-id pictures. silhouettes: (N, K, H, W) bool, each actor rendered with
    everything else hidden. actor_ids: (N, K) each actor's id (any value for padding). see_through: ids of floor
    decals that hide nothing. occluders: category -> ids for OCCLUDERS but the last (`occluder_ids`); None: what
    hides the actors is not counted. Returns arrays of the inputs' kind: unoccluded (N, K), visible (N, K),
    full_box / visible_box (N, K, 4), full_empty / visible_empty (N, K) bool, border (N, K) bool, and with
    occluders hidden_by (N, K, len(OCCLUDERS)): hidden pixels per category.
    """
    if len(ids.shape) != 3 or len(silhouettes.shape) != 4 or silhouettes.shape[0] != ids.shape[0] \
            or tuple(silhouettes.shape[2:]) != tuple(ids.shape[1:]) \
            or tuple(actor_ids.shape) != tuple(silhouettes.shape[:2]):
        raise ValueError(f"ids {tuple(ids.shape)}, silhouettes {tuple(silhouettes.shape)} and actor ids "
                         f"{tuple(actor_ids.shape)} do not describe N frames of K actors")
    shown = ids[:, None] == actor_ids[:, :, None, None]  # (N, K, H, W)
    if len(see_through):
        # Decal pixels (a shadow over a tyre's last millimetre) hide nothing.
        shown = shown | arrays.isin(ids, see_through)[:, None]
    visible = shown & silhouettes
    full_box, full_empty = mask_boxes(silhouettes)
    visible_box, visible_empty = mask_boxes(visible)
    border = (silhouettes[..., 0, :].any(axis=-1) | silhouettes[..., -1, :].any(axis=-1)
              | silhouettes[..., :, 0].any(axis=-1) | silhouettes[..., :, -1].any(axis=-1))
    out = {"unoccluded": silhouettes.sum(axis=(-2, -1)), "visible": visible.sum(axis=(-2, -1)),
           "full_box": full_box, "full_empty": full_empty, "visible_box": visible_box,
           "visible_empty": visible_empty, "border": border}
    if occluders is not None:
        out["hidden_by"] = hidden_by(ids, silhouettes & ~shown, occluders)
    return out


def hidden_by(ids, hidden, occluders: Mapping):
    """(N, K, len(OCCLUDERS)) counts of the hidden pixels (N, K, H, W) per category: those of `occluders`' ids
    (category -> ids), then `structure`, every other drawn id (id 0 draws nothing, so hides nothing)."""
    named = [list(occluders.get(category, ())) for category in OCCLUDERS[:-1]]
    # Each id's category by table lookup (an id past the named ones: structure, the table's last entry).
    lut = np.full(max((max(v) for v in named if v), default=0) + 2, len(OCCLUDERS) - 1, np.int64)
    lut[0] = len(OCCLUDERS)  # no category
    for c, wanted in enumerate(named):
        lut[wanted] = c
    code = arrays.take(arrays.table(lut, ids), ids.clip(0, len(lut) - 1))  # (N, H, W)
    n, k = hidden.shape[:2]
    if not arrays.is_torch(hidden):
        return _hidden_counts(code, hidden)
    which = code[..., None] == arrays.table(np.arange(len(OCCLUDERS)), ids)  # (N, H, W, C)
    # One product counts every actor's hidden pixels in every category: (N, K, HW) @ (N, HW, C); float32 counts
    # are exact up to 2^24 pixels.
    counts = (arrays.cast(hidden, np.float32).reshape(n, k, -1)
              @ arrays.cast(which, np.float32).reshape(n, -1, len(OCCLUDERS)))
    return arrays.as_int(counts)


def _hidden_counts(code: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    """hidden_by's counts on the CPU: each hidden pixel's (frame and actor, category) counted by bincount. The
    product above reads every pixel of every actor as a float (K x H x W of them); a silhouette's hidden pixels
    are a small share of a frame, so finding them and counting is 2-4x faster (1.5 -> 0.5 ms for ten actors at
    320 x 240, measured on an Intel Xeon). The counts are the same integers (tests/test_groundtruth.py)."""
    n, k = hidden.shape[:2]
    per = len(OCCLUDERS) + 1  # the categories, then "none" (id 0), which is dropped
    size = code[0].size
    actor, pixel = np.divmod(np.flatnonzero(hidden), size)  # actor: frame * K + actor
    category = code.reshape(n, size)[actor // k, pixel]
    counts = np.bincount(actor * per + category, minlength=n * k * per).reshape(n, k, per)[..., :-1]
    return counts.astype(np.int32)


def stats_of(batch: dict, names: Sequence[Sequence[str]]) -> list[list[MaskStats]]:
    """`batch_mask_stats`' numbers as `MaskStats`, frame by frame (names[n]: frame n's actors, in silhouette
    order; padding beyond them is dropped). One copy to the CPU per array for the whole batch."""
    host = {k: v.tolist() for k, v in batch.items()}
    out = []
    for n, frame_names in enumerate(names):
        row = []
        for k, name in enumerate(frame_names):
            if host["full_empty"][n][k]:
                row.append(MaskStats(name, 0, 0, None, None, False))
                continue
            visible_box = None if host["visible_empty"][n][k] else tuple(host["visible_box"][n][k])
            hidden = tuple(int(c) for c in host["hidden_by"][n][k]) if "hidden_by" in host else ()
            row.append(MaskStats(name, int(host["unoccluded"][n][k]), int(host["visible"][n][k]),
                                 tuple(host["full_box"][n][k]), visible_box, bool(host["border"][n][k]), hidden))
        out.append(row)
    return out


def mask_stats(frame: Frame, silhouettes: Mapping[str, object], ids: Mapping[str, int],
               occluders: Mapping | None = None) -> list[MaskStats]:
    """Each actor's `MaskStats` on one frame, in the order of `silhouettes` (see `ground_truth`): a batch of one
    frame. The frame's ids and the silhouettes are numpy arrays or torch tensors alike. occluders: as
    `batch_mask_stats` (`occluder_ids`; None: what hides them is not counted)."""
    names = list(silhouettes)
    if not names:
        return []
    for name in names:
        if tuple(silhouettes[name].shape) != tuple(frame.ids.shape):
            raise ValueError(f"silhouette of {name} is {tuple(silhouettes[name].shape)}, "
                             f"the frame {tuple(frame.ids.shape)}")
    stack = arrays.xp(frame.ids).stack
    masks = stack([silhouettes[m] for m in names])[None]
    if str(masks.dtype).rsplit(".", 1)[-1] != "bool":
        masks = masks != 0
    actor_ids = arrays.table(np.array([[ids[m] for m in names]], dtype=np.int32), frame.ids)
    batch = batch_mask_stats(frame.ids[None], masks, actor_ids, sorted(frame.see_through), occluders)
    return stats_of(batch, [names])[0]


def ground_truth(frame: Frame, silhouettes: Mapping[str, np.ndarray], scene: Scene,
                 ids: Mapping[str, int]) -> list[VehicleTruth]:
    """One record per vehicle with a non-empty unoccluded silhouette (a vehicle is "in view" when it would be
    seen with nothing in the way), in the order of `silhouettes`.

    silhouettes: name -> HxW bool mask (`renderer.unoccluded_ids`); ids: name -> segmentation id
    (`renderer.ids`). Poses come from the frame (where the vehicles stood when it was rendered), falling back to
    the description's.
    """
    return truth_records(frame, mask_stats(frame, silhouettes, ids, occluder_ids(frame, scene, ids)), scene)


def truth_records(frame: Frame, stats: list[MaskStats], scene: Scene) -> list[VehicleTruth]:
    """The records of the actors whose silhouettes are not empty: the pixel counts and boxes of `stats`, the
    geometry (distance, truncation, off-axis angle) from the frame's camera and poses."""
    camera = frame.position
    out = []
    for st in stats:
        if st.full_box is None:
            continue
        name, full_box = st.name, st.full_box
        entity = scene.entity(name)
        pose = frame.poses.get(name, entity.pose)
        fraction = st.visible_pixels / st.unoccluded_pixels
        corners = world_corners(entity, pose)
        if corners is not None:
            centre = (corners.min(axis=0) + corners.max(axis=0)) / 2
            truncation = projected_truncation(frame, corners)
            height = float(corners[:, 2].max() - corners[:, 2].min())
        else:
            centre = np.array([pose.x, pose.y, pose.z])
            truncation = 1.0 if st.touches_border else 0.0
            height = 0.0  # no extent to measure (and NaN would make equal records unequal)
        occ = occlusion_state(fraction)
        out.append(VehicleTruth(
            name=name, role=entity.role, visible_pixels=st.visible_pixels, unoccluded_pixels=st.unoccluded_pixels,
            visible_fraction=fraction, visible_box=st.visible_box, full_box=full_box,
            distance=float(np.linalg.norm(centre - camera)), truncation=truncation, occlusion=occ,
            kitti=kitti_level(full_box[3] - full_box[1], fraction, truncation),
            kind="person" if entity.is_person else "vehicle", off_axis=_off_axis(frame, centre),
            occluder=occluder_category(st.hidden_by, st.unoccluded_pixels), height=height,
            light=direct_light(scene, centre), camera_height=float(camera[2])))
    return out


def direct_light(scene: Scene, point) -> float:
    """How much the garage's lamps light a point: the sum over the scene's point lights of intensity / d^2
    (the renderer's units: a lamp of intensity 1 at 1 m gives 1; the `light` preset's coverage, intensity and
    failed lamps all show in it), with no shadowing and no ambient term. A target's `light` (the frame table's
    `target_light`) is the value at its 3D box's centre: what lights it, wherever it stands."""
    if not scene.lights:
        return 0.0
    positions = np.array([light.position for light in scene.lights], dtype=float)
    intensity = np.array([light.intensity for light in scene.lights], dtype=float)
    d2 = np.maximum(((positions - np.asarray(point, dtype=float)) ** 2).sum(axis=1), 0.25)  # within 0.5 m: as at 0.5
    return round(float((intensity / d2).sum()), 6)


def _off_axis(frame: Frame, point: np.ndarray) -> float:
    ray = np.asarray(point, dtype=float) - frame.position
    cos = ray @ frame.cam_to_world[:3, 0] / max(float(np.linalg.norm(ray)), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])],
                    dtype=float)


def _place(points: np.ndarray, pose: Pose) -> np.ndarray:
    c, s = np.cos(np.radians(pose.yaw)), np.sin(np.radians(pose.yaw))
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return points @ rot.T + np.array([pose.x, pose.y, pose.z])


# The 12 edges of a box whose corners come from _corners (index bits: x, y, z).
_EDGES = [(a, a | bit) for a in range(8) for bit in (1, 2, 4) if not a & bit]


def _clip_near(local: np.ndarray, near: float) -> np.ndarray:
    """Corners in front of the near plane plus the points where box edges cross it (camera frame, x forward)."""
    front = local[:, 0] >= near
    points = [local[front]]
    for a, b in _EDGES:
        if front[a] != front[b]:
            t = (near - local[a, 0]) / (local[b, 0] - local[a, 0])
            points.append((local[a] + t * (local[b] - local[a]))[None])
    return np.concatenate(points, axis=0)


