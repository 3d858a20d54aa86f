"""The baseline slot detector: classical OpenCV on a bird's-eye view, no weights.

1. Paint: white paint is bright in every colour channel (yellow lane paint is not), so the image's smallest
   channel is top-hat filtered (a kernel 2x the widest line: what is left is thin and brighter than the floor
   around it) and thresholded at `min_contrast` or four robust noise deviations, whichever is higher. A strip
   of floor between a dark car and the dark lane passes that too, so paint must also lie in the upper half
   between the floor under it and the brightest pixel within a bay width (the next line, usually). Specks
   smaller than a 0.15 x 0.13 m piece of paint go.
2. Lines: probabilistic Hough segments of the paint, merged into painted lines when they are parallel, on one
   centre line (within the widest line) and no more than `max_gap` apart along it (worn paint).
3. Roles: a line with a parallel neighbour a bay width away (the lines overlapping along their length) is a
   separating line; any other line at least `min_line` long may be an entrance line.
4. Marking points: where a separating line's end meets an entrance line (within `junction`), at the crossing of
   their centre lines ("T" when the entrance line goes on past it, else "L"); with no entrance line painted
   (the project's garage paints none), the separating line's end nearer the image centre, where the ego is,
   unless that end is cut by the image edge or by pixels no camera saw. The direction points along the line,
   away from that end. Its score is the share of the line's first metre from it that is paint. Without an
   entrance line, its shape follows its slots: "T" between two, else "L".
5. Slots: neighbouring marking points with parallel directions whose distance is a bay width, each point
   paired at most once on either side, nearest first; the quad is the entrance pushed back by the depth seen
   (both separating lines' far ends seen and within `depth`), else by the middle of `depth`.
6. Occupancy: the slot's inner part (its quad shrunk by 20%) against the floor's colour, measured beside the
   painted lines (0.1-0.3 m off them, where parked cars leave the floor bare): occupied when at least
   `occupied_fraction` of it is further from that colour than `occupied_delta` times the colour's own length
   (RGB distances, so dim light decides alike); undecided when less than half of it was seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from garage_exp.slots.marks import MarkingPoint, Slot, SlotFrame
from garage_exp.slots.schema import SlotLinesConf

INSET = 0.2  # the occupancy test skips this share of the quad at its edges (the lines, a neighbour's overhang)
MERGE_DEG = 5.0  # Hough segments within this angle may be one painted line
SUPPORT = 1.0  # metres of its line from the point that a marking point's score is measured over


@dataclass
class Line:
    """A painted line: its two ends (col, row), unit direction a -> b, and the share of it that is painted."""

    a: np.ndarray
    b: np.ndarray
    coverage: float

    @property
    def length(self) -> float:
        return float(np.linalg.norm(self.b - self.a))

    @property
    def unit(self) -> np.ndarray:
        return (self.b - self.a) / max(self.length, 1e-9)


def paint_mask(image: np.ndarray, mpp: float, p) -> tuple[np.ndarray, np.ndarray]:
    """(paint, seen): uint8 0/255 paint mask, and the pixels some camera saw (not pure black)."""
    import cv2

    seen = image.max(axis=2) > 2
    white = image.min(axis=2)
    k = max(3, int(round(2 * float(p.line_width[1]) / mpp)) | 1)  # wider bright patches (a windscreen) are not paint
    tophat = cv2.morphologyEx(white, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, k)))
    values = tophat[seen].astype(np.float32)
    if values.size == 0:
        return np.zeros_like(white), seen
    med = float(np.median(values))
    mad = float(np.median(np.abs(values - med))) * 1.4826
    # A strip of floor between a dark car and the dark lane is thin and bright too; paint is also in the upper
    # half between the floor under it and the brightest thing within a bay width (usually the next line).
    k_near = max(3, int(round(float(p.bay_width[1]) / mpp)) | 1)
    brightest = cv2.dilate(white, cv2.getStructuringElement(cv2.MORPH_RECT, (k_near, k_near)))
    upper = 2 * white.astype(np.int16) >= brightest.astype(np.int16) + (white - tophat).astype(np.int16)
    paint = ((tophat > max(float(p.min_contrast), med + 4 * mad)) & upper & seen).astype(np.uint8) * 255
    n, labels, stats, _ = cv2.connectedComponentsWithStats(paint, connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] < 0.02 / (mpp * mpp)
    small[0] = False
    paint[small[labels]] = 0
    return paint, seen


def thin(mask: np.ndarray, iterations: int) -> np.ndarray:
    """Zhang-Suen thinning (1984), at most `iterations` passes: painted lines down to their centre lines (Hough
    segments on a thick line also run diagonally across it)."""
    img = np.pad((mask > 0).astype(np.uint8), 1)
    for _ in range(iterations):
        changed = False
        for step in (0, 1):
            p2, p3, p4, p5 = img[:-2, 1:-1], img[:-2, 2:], img[1:-1, 2:], img[2:, 2:]
            p6, p7, p8, p9 = img[2:, 1:-1], img[2:, :-2], img[1:-1, :-2], img[:-2, :-2]
            ring = [p2, p3, p4, p5, p6, p7, p8, p9, p2]
            neighbours = sum(ring[:8])
            rises = sum(((ring[k] == 0) & (ring[k + 1] == 1)).astype(np.uint8) for k in range(8))
            if step == 0:
                clear = ((p2 & p4 & p6) == 0) & ((p4 & p6 & p8) == 0)
            else:
                clear = ((p2 & p4 & p8) == 0) & ((p2 & p6 & p8) == 0)
            centre = img[1:-1, 1:-1]
            drop = (centre == 1) & (neighbours >= 2) & (neighbours <= 6) & (rises == 1) & clear
            if drop.any():
                changed = True
                centre[drop] = 0
        if not changed:
            break
    return img[1:-1, 1:-1] * 255


def segments(paint: np.ndarray, mpp: float, p) -> np.ndarray:
    """Hough segments (n, 4) on the paint's centre lines: x1, y1, x2, y2."""
    import cv2

    skeleton = thin(paint, int(float(p.line_width[1]) / mpp / 2) + 3)
    min_len = max(5, int(0.4 / mpp))
    found = cv2.HoughLinesP(skeleton, 1, math.pi / 360, threshold=max(5, min_len // 2), minLineLength=min_len,
                            maxLineGap=max(1, int(float(p.max_gap) / mpp)))
    return np.zeros((0, 4), np.float32) if found is None else found.reshape(-1, 4).astype(np.float32)


def merge(segs: np.ndarray, mpp: float, p) -> list[Line]:
    """Segments joined into painted lines (union-find over compatible pairs)."""
    n = len(segs)
    if n == 0:
        return []
    a, b = segs[:, :2], segs[:, 2:]
    d = b - a
    length = np.linalg.norm(d, axis=1)
    u = d / np.maximum(length, 1e-9)[:, None]
    width = float(p.line_width[1]) / mpp / 2 + 2
    gap = float(p.max_gap) / mpp + 2
    cos_merge = math.cos(math.radians(MERGE_DEG))
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(n):
        for j in range(i + 1, n):
            if abs(float(u[i] @ u[j])) < cos_merge:
                continue
            normal = np.array([-u[i][1], u[i][0]])
            if max(abs(float((a[j] - a[i]) @ normal)), abs(float((b[j] - a[i]) @ normal))) > width:
                continue
            ti = sorted((0.0, float(length[i])))
            tj = sorted((float((a[j] - a[i]) @ u[i]), float((b[j] - a[i]) @ u[i])))
            if max(tj[0] - ti[1], ti[0] - tj[1]) > gap:
                continue
            parent[find(i)] = find(j)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    return [_fit(a[idx], b[idx], length[idx]) for idx in map(np.array, groups.values())]


def _fit(a: np.ndarray, b: np.ndarray, length: np.ndarray) -> Line:
    """One line through a group's segments: the length-weighted mean direction and centre, the extremes of
    their ends along it, and the share of that span the segments cover."""
    d = b - a
    ref = d[int(np.argmax(length))]
    d = np.where((d @ ref)[:, None] < 0, -d, d)  # one sense for all before averaging
    u = d.sum(axis=0)
    u = u / max(float(np.linalg.norm(u)), 1e-9)
    w = length / max(float(length.sum()), 1e-9)
    centre = ((a + b) / 2 * w[:, None]).sum(axis=0)
    ta, tb = (a - centre) @ u, (b - centre) @ u
    lo, hi = float(min(ta.min(), tb.min())), float(max(ta.max(), tb.max()))
    covered = np.zeros(max(1, int(math.ceil(hi - lo)) + 1), bool)
    for s, e in zip(np.minimum(ta, tb), np.maximum(ta, tb)):
        covered[int(s - lo):int(math.ceil(e - lo)) + 1] = True
    return Line(centre + lo * u, centre + hi * u, float(covered.mean()))


def separating(lines: list[Line], mpp: float, p) -> list[bool]:
    """Which lines have a parallel neighbour a bay width away, overlapping along their length."""
    cos_par = math.cos(math.radians(float(p.parallel_deg)))
    lo, hi = (float(v) / mpp for v in p.bay_width)
    out = [False] * len(lines)
    for i, li in enumerate(lines):
        if li.length * mpp < float(p.min_line):
            continue
        u = li.unit
        normal = np.array([-u[1], u[0]])
        for j, lj in enumerate(lines):
            if j == i or lj.length * mpp < float(p.min_line) or abs(float(u @ lj.unit)) < cos_par:
                continue
            mid = (lj.a + lj.b) / 2
            if not lo <= abs(float((mid - li.a) @ normal)) <= hi:
                continue
            ta, tb = sorted((float((lj.a - li.a) @ u), float((lj.b - li.a) @ u)))
            overlap = min(tb, li.length) - max(ta, 0.0)
            if overlap >= 0.3 * min(li.length, lj.length):
                out[i] = True
                break
    return out


def _cross_point(p0: np.ndarray, u0: np.ndarray, p1: np.ndarray, u1: np.ndarray) -> np.ndarray | None:
    m = np.array([u0, -u1]).T
    if abs(float(np.linalg.det(m))) < 1e-6:
        return None
    s, _ = np.linalg.solve(m, p1 - p0)
    return p0 + s * u0


def _is_cut(point: np.ndarray, seen: np.ndarray, margin: int) -> bool:
    """An end at the image edge or beside pixels no camera saw: the paint may go on past it."""
    h, w = seen.shape
    x, y = int(round(point[0])), int(round(point[1]))
    if x < margin or y < margin or x >= w - margin or y >= h - margin:
        return True
    return not seen[max(0, y - margin):y + margin + 1, max(0, x - margin):x + margin + 1].all()


def _extend(end: np.ndarray, outward: np.ndarray, paint: np.ndarray, reach: float) -> np.ndarray:
    """The centre line's end pushed out to where the paint ends (thinning stops about half a width short)."""
    h, w = paint.shape
    last = end
    for step in np.arange(0.5, reach, 0.5):
        x, y = end + step * outward
        col, row = int(x), int(y)
        if not (0 <= col < w and 0 <= row < h) or not paint[row, col]:
            break
        last = end + step * outward
    return last


def support(near: np.ndarray, at: np.ndarray, direction: np.ndarray, reach: float) -> float:
    """A marking point's score: the share of its separating line's first `reach` pixels (from the point, along
    its direction) that is paint (`near`: the paint grown by a pixel). Worn paint near the entrance scores low."""
    h, w = near.shape
    steps = np.arange(0.0, reach, 1.0)
    xs = np.round(at[0] + steps * direction[0]).astype(int)
    ys = np.round(at[1] + steps * direction[1]).astype(int)
    inside = (xs >= 0) & (xs < w) & (ys >= 0) & (ys < h)
    if not inside.any():
        return 0.0
    return round(float(near[ys[inside], xs[inside]].mean()), 4)


def marking_points(lines: list[Line], roles: list[bool], paint: np.ndarray, seen: np.ndarray, mpp: float,
                   p) -> tuple[list[MarkingPoint], list[Line]]:
    """One marking point per separating line (where it meets its entrance), and that line (ends ordered
    entrance first). A point with no entrance line is "L" until pairing tells (`shapes_by_pairing`)."""
    import cv2

    near_paint = cv2.dilate(paint, np.ones((3, 3), np.uint8)) > 0
    h, w = seen.shape
    centre = np.array([w / 2, h / 2])
    junction = float(p.junction) / mpp
    margin = max(1, int(round(float(p.border) / mpp)))
    entrances = [ln for ln, sep in zip(lines, roles) if not sep and ln.length * mpp >= float(p.min_line)]
    points, owners = [], []
    for line, sep in zip(lines, roles):
        if not sep:
            continue
        u = line.unit
        best = None
        for end, other, sign in ((line.a, line.b, 1.0), (line.b, line.a, -1.0)):
            for ent in entrances:
                if abs(float(u @ ent.unit)) > math.cos(math.radians(30.0)):
                    continue  # too near parallel to be its entrance
                x = _cross_point(line.a, u, ent.a, ent.unit)
                if x is None or np.linalg.norm(x - end) > junction:
                    continue
                t = float((x - ent.a) @ ent.unit)
                if not -junction <= t <= ent.length + junction:
                    continue
                shape = "T" if junction < t < ent.length - junction else "L"
                dist = float(np.linalg.norm(x - end))
                if best is None or dist < best[0]:
                    best = (dist, x, sign * u, shape, Line(x, other, line.coverage))
        if best is None:  # no entrance line: the end nearer the ego, if it is a real end
            a_first = np.linalg.norm(line.a - centre) <= np.linalg.norm(line.b - centre)
            near, far, sign = (line.a, line.b, 1.0) if a_first else (line.b, line.a, -1.0)
            if _is_cut(near, seen, margin):
                continue
            near = _extend(near, (near - far) / max(float(np.linalg.norm(near - far)), 1e-9), paint,
                           float(p.line_width[1]) / mpp)
            best = (0.0, near, sign * u, "", Line(near, far, line.coverage))
        _, at, direction, shape, owner = best
        points.append(MarkingPoint(float(at[0]), float(at[1]), math.atan2(float(direction[1]), float(direction[0])),
                                   shape, score=support(near_paint, at, direction, SUPPORT / mpp)))
        owners.append(owner)
    return points, owners


def pair_points(points: list[MarkingPoint], mpp: float, p, depths: list[float | None] | None = None) -> list[Slot]:
    """Slots between neighbouring marking points a bay width apart with parallel directions, nearest first,
    each point used at most once on either side. Corners run entrance p1, p2, back of p2, back of p1, with p1
    and p2 ordered so that the slot lies clockwise of p1 -> p2 on the image (rows grow downwards).
    depths: per point, the depth seen along its separating line (pixels), None where its far end was not seen."""
    lo, hi = (float(v) / mpp for v in p.bay_width)
    dlo, dhi = (float(v) / mpp for v in p.depth)
    cos_par = math.cos(math.radians(float(p.parallel_deg)))
    dirs = [np.array([math.cos(q.direction), math.sin(q.direction)]) for q in points]
    xy = [np.array([q.x, q.y]) for q in points]
    candidates = []
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            v = xy[j] - xy[i]
            dist = float(np.linalg.norm(v))
            if not lo <= dist <= hi or float(dirs[i] @ dirs[j]) < cos_par:
                continue
            if abs(float(dirs[i] @ v)) / dist > 0.5:  # an entrance runs at least 30 degrees off the lines
                continue
            candidates.append((dist, i, j))
    used: set[tuple[int, int]] = set()
    slots = []
    for _, i, j in sorted(candidates):
        v = xy[j] - xy[i]
        side = 1 if dirs[i][0] * v[1] - dirs[i][1] * v[0] > 0 else -1
        if (i, side) in used or (j, -side) in used:
            continue
        used.update({(i, side), (j, -side)})
        d = dirs[i] + dirs[j]
        d /= max(float(np.linalg.norm(d)), 1e-9)
        seen = [depths[k] for k in (i, j) if depths and depths[k] is not None and dlo <= depths[k] <= dhi]
        depth = float(np.mean(seen)) if seen else (dlo + dhi) / 2
        p1, p2 = (i, j) if d[0] * v[1] - d[1] * v[0] < 0 else (j, i)
        a, b = xy[p1], xy[p2]
        corners = tuple((float(c[0]), float(c[1])) for c in (a, b, b + depth * d, a + depth * d))
        score = min(points[i].score, points[j].score)
        slots.append(Slot(p1, p2, corners, score=score))
    return slots


def shapes_by_pairing(points: list[MarkingPoint], slots: list[Slot]) -> list[MarkingPoint]:
    """Points found without an entrance line (shape "") take it from their slots: "T" between two, else "L"."""
    uses = [0] * len(points)
    for s in slots:
        uses[s.p1] += 1
        uses[s.p2] += 1
    return [q if q.shape else MarkingPoint(q.x, q.y, q.direction, "T" if n >= 2 else "L", q.score)
            for q, n in zip(points, uses)]


def floor_colour(image: np.ndarray, paint: np.ndarray, seen: np.ndarray, mpp: float) -> np.ndarray:
    """The median colour 0.1-0.3 m beside the paint (the bay floor parked cars leave bare), else of all seen
    pixels that are not paint."""
    import cv2

    def grown(metres: float) -> np.ndarray:
        k = max(3, int(round(2 * metres / mpp)) | 1)
        return cv2.dilate(paint, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))) > 0

    ring = grown(0.3) & ~grown(0.1) & seen
    if ring.sum() < 50:
        ring = seen & (paint == 0)
    if not ring.any():
        return np.zeros(3)
    return np.median(image[ring].reshape(-1, 3), axis=0)


def occupancy(image: np.ndarray, seen: np.ndarray, corners, floor: np.ndarray, p) -> bool | None:
    """Occupied when enough of the slot's inner part is not floor-coloured; None when too little was seen."""
    import cv2

    quad = np.array(corners, np.float64)
    mid = quad.mean(axis=0)
    inner = mid + (quad - mid) * (1 - INSET)
    mask = np.zeros(seen.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(inner * 4).astype(np.int32), 1, shift=2)
    area = mask.sum()
    inside = (mask > 0) & seen
    if area == 0 or inside.sum() < 0.5 * area:
        return None
    dist = np.linalg.norm(image[inside].astype(np.float32) - floor.astype(np.float32), axis=1)
    # relative to the floor's own brightness, so that dim light (every difference smaller) decides alike
    far = dist > float(p.occupied_delta) * max(float(np.linalg.norm(floor)), 10.0)
    return bool(far.mean() >= float(p.occupied_fraction))


def detect(image: np.ndarray, mpp: float, p) -> SlotFrame:
    """The baseline on one BEV image (H, W, 3 uint8 RGB) of `mpp` metres per pixel; p: the `lines` settings."""
    image = np.ascontiguousarray(image[..., :3])
    paint, seen = paint_mask(image, mpp, p)
    lines = merge(segments(paint, mpp, p), mpp, p)
    points, owners = marking_points(lines, separating(lines, mpp, p), paint, seen, mpp, p)
    margin = max(1, int(round(float(p.border) / mpp)))
    depths = [None if _is_cut(ln.b, seen, margin) else ln.length for ln in owners]
    slots = pair_points(points, mpp, p, depths)
    points = shapes_by_pairing(points, slots)
    floor = floor_colour(image, paint, seen, mpp)
    slots = [Slot(s.p1, s.p2, s.corners, occupancy(image, seen, s.corners, floor, p), s.score) for s in slots]
    return SlotFrame(points, slots, float(mpp), (int(image.shape[1]), int(image.shape[0])))


def baseline(image: np.ndarray, mpp: float) -> SlotFrame:
    """The baseline with its default settings, as a user's function is called (`slot_detector=callable`'s
    example target)."""
    return detect(image, mpp, SlotLinesConf())
