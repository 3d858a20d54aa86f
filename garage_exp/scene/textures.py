"""Procedural, seeded textures for the `real` look: worn concrete, lane asphalt, dirty wall paint, hazard
stripes, worn line paint, signs and the soft shadows under things. No asset packs: every picture is made here
from a `Texture` spec with numpy, so a renderer, the glTF export and a test all get the same pixels.

Pictures are linear RGBA float32 (H x W x 4), plus a roughness map where the surface is not uniform (oil and
puddles shine). A box's picture tiles: noise is periodic (wrapped), so a floor of many boxes shows no seams.
"""

from __future__ import annotations

import math
import zlib

import numpy as np

from garage_exp.core.state import STATE
from garage_exp.core.errors import GarageError
from garage_exp.scene.description import Material, Texture

PX_PER_M = 96  # texels per metre of a tiled texture: ~1 cm, finer than a pixel of the front camera past 2 m
MAX_SIZE = 512
DECAL_SIZE = 128


def _size(tex: Texture) -> int:
    return int(min(MAX_SIZE, max(32, round(tex.tile * PX_PER_M)))) if tex.tile > 0 else DECAL_SIZE


def fbm(size: int, rng: np.random.Generator, octaves: int = 5, base: int = 4, falloff: float = 0.55) -> np.ndarray:
    """Periodic fractal noise, about [-1, 1]: white noise filtered in the Fourier domain to the band from `base`
    to base * 2^(octaves - 1) cycles per tile, each octave `falloff` times weaker than the one below. Periodic by
    construction (the tile repeats without a seam) and ~5 ms at 384 px, where octaves of upsampled grids took
    ~50 ms."""
    fy = np.fft.fftfreq(size)[:, None] * size
    fx = np.fft.rfftfreq(size)[None, :] * size
    f = np.sqrt(fx ** 2 + fy ** 2)
    top = base * 2 ** (octaves - 1)
    band = (f >= base / 1.5) & (f <= top * 1.5)
    # amplitude per unit of log-frequency follows falloff per octave; per unit of frequency that is f^(a - 1)
    gain = np.where(band, (np.maximum(f, 1e-6) / base) ** (math.log2(falloff) - 1.0), 0.0)
    noise = np.fft.irfft2(np.fft.rfft2(rng.standard_normal((size, size))) * gain, s=(size, size))
    std = float(noise.std())
    return (noise / (3.0 * std) if std > 0 else noise).astype(np.float32)


def _blobs(size: int, rng: np.random.Generator, count: int, radius: tuple[float, float],
           stretch: float = 1.0) -> np.ndarray:
    """Soft periodic blobs (stains, puddles, tyre smears) in [0, 1]. Each is computed in its own window (wrapped
    around the tile's edges), not over the whole picture: a replicate redraws a floor in ~0.1 s, not 0.5."""
    out = np.zeros((size, size), dtype=np.float32)
    for _ in range(count):
        cx, cy = rng.random(2)
        r = rng.uniform(*radius)
        angle = rng.uniform(0, math.pi)
        strength = rng.uniform(0.5, 1.0)
        half = min(size // 2, int(math.ceil(1.6 * r * max(stretch, 1.0) * size)))
        ix = (np.arange(-half, half + 1) + int(cx * size)) % size
        iy = (np.arange(-half, half + 1) + int(cy * size)) % size
        offsets = (np.arange(-half, half + 1, dtype=np.float32) + (int(cx * size) - cx * size)) / size
        dx, dy = offsets[None, :], ((np.arange(-half, half + 1, dtype=np.float32) + (int(cy * size) - cy * size))
                                    / size)[:, None]
        u = dx * math.cos(angle) + dy * math.sin(angle)
        v = -dx * math.sin(angle) + dy * math.cos(angle)
        blob = np.exp(-((u / (r * stretch)) ** 2 + (v / r) ** 2) * 2.0) * strength
        window = np.ix_(iy, ix)
        out[window] = np.maximum(out[window], blob)
    return out


def _cracks(size: int, rng: np.random.Generator, count: int) -> np.ndarray:
    """Thin dark random-walk lines in [0, 1] (1: crack)."""
    import cv2

    canvas = np.zeros((size * 3, size * 3), dtype=np.uint8)  # drawn on a 3x3 tiling, the middle tile kept
    for _ in range(count):
        p = rng.random(2) * size + size
        heading = rng.uniform(0, 2 * math.pi)
        points = [p.copy()]
        for _ in range(int(rng.integers(6, 14))):
            heading += rng.normal(0, 0.5)
            p = p + np.array([math.cos(heading), math.sin(heading)]) * size * rng.uniform(0.02, 0.06)
            points.append(p.copy())
        cv2.polylines(canvas, [np.array(points, dtype=np.int32)], False, 255, 1, cv2.LINE_AA)
    tiles = canvas.reshape(3, size, 3, size).max(axis=(0, 2))
    return tiles.astype(np.float32) / 255.0


def _rgba(colour: np.ndarray, shade: np.ndarray, alpha: np.ndarray | None = None) -> np.ndarray:
    """The picture (float32 RGBA) of `colour` shaded, clipped to [0, 1], computed in the colour's precision and
    written into the picture a channel at a time: the product broadcast over three channels ran numpy's inner loop
    three elements long, casting each (4.4 -> 0.9 ms at 480 px on the Zen 5, the same bytes; a scenario of the wide
    space makes about ten)."""
    out = np.empty(shade.shape + (4,), np.float32)
    channel = np.empty(shade.shape, np.result_type(colour, shade))
    for k in range(3):
        np.multiply(shade, colour[k], out=channel, dtype=channel.dtype)
        np.clip(channel, 0.0, 1.0, out=channel)
        out[..., k] = channel
    out[..., 3] = 1.0 if alpha is None else alpha
    return out


def _rng(kind: str, seed: int) -> np.random.Generator:
    """A picture's random numbers: by its kind and seed (str hash() varies by process)."""
    return np.random.default_rng([zlib.crc32(kind.encode()), seed])


# A wide space draws the floor's grime and wetness per scenario, and every dressed surface's picture carries the
# grime: each scenario made its garage's floors, walls and ceilings again (~0.1 s a scenario), though their noise
# fields, drawn first from the picture's own random numbers, depend only on its kind, seed and size. Those fields
# are kept (`_start`), with the random numbers' state after them, so that the rest of the picture draws exactly
# the numbers it drew before: the same pixels.
@STATE.memo("process", maxsize=64)
def _start(kind: str, seed: int, size: int, draw) -> tuple[tuple[np.ndarray, ...], dict]:
    """`draw(rng, size)`'s fields (read-only) for a picture of this kind, seed and size, and its rng's state
    after them."""
    rng = _rng(kind, seed)
    fields = tuple(draw(rng, size))
    for field in fields:
        field.setflags(write=False)
    return fields, rng.bit_generator.state


def _started(tex: Texture, rng: np.random.Generator, size: int, draw) -> tuple[np.ndarray, ...]:
    """The picture's first fields (`_start`), its `rng` moved on past them."""
    fields, state = _start(tex.kind, tex.seed, size, draw)
    rng.bit_generator.state = state
    return fields


def _floor_fields(rng, size: int):
    return (1.0 + 0.18 * fbm(size, rng) + 0.05 * fbm(size, rng, octaves=3, base=32),)


def _wall_fields(rng, size: int):
    return fbm(size, rng), fbm(size, rng, octaves=3, base=16)


def _ceiling_fields(rng, size: int):
    return fbm(size, rng), _blobs(size, rng, 3, (0.05, 0.12))


def _stripes_fields(rng, size: int):
    return fbm(size, rng), _blobs(size, rng, 3, (0.05, 0.1))


def _paint_fields(rng, size: int):
    return fbm(size, rng, octaves=5, base=8), fbm(size, rng, octaves=3, base=32)


def _arrow_fields(rng, size: int):
    return (fbm(size, rng, base=8),)


def _floor(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, np.ndarray]:
    grime, wet = float(tex.param("grime", 0.5)), float(tex.param("wetness", 0.0))
    shade = _started(tex, rng, size, _floor_fields)[0].copy()
    rough = np.full((size, size), mat.roughness, np.float32)
    counts = (int(3 + 7 * grime), int(4 + 10 * grime), int(1 + 3 * grime)) if grime > 0 else None
    stains, smears, cracks, puddled = _grime(tex.kind, tex.seed, size, counts)
    if grime > 0:
        shade *= 1.0 - 0.6 * grime * stains - 0.35 * grime * smears
        shade *= 1.0 - 0.5 * cracks
        rough -= 0.35 * stains * grime  # oil shines
    if wet > 0:
        rough *= 1.0 - 0.5 * wet  # a damp film everywhere, puddles where the floor dips
        puddles = puddled * wet
        shade *= 1.0 - 0.3 * puddles  # wet concrete darkens
        rough = rough * (1.0 - puddles) + 0.1 * puddles  # glossy, not a mirror: a lamp's reflection is a blob
    return _rgba(np.asarray(mat.color), shade), np.clip(rough, 0.03, 1.0)


# A floor's stains, smears and cracks are drawn in numbers set by its grime (3-10, 4-14, 1-4: a dozen settings
# over grime's range), then its puddles' noise: the same numbers for a kind, seed, size and those counts,
# whatever the grime's exact value, which only weighs them. A wide space draws grime and wetness per scenario:
# the layers are kept, so a floor is a few weighted sums (~2 ms), not their drawing again (~8 ms, ten floors a
# scenario of five).
@STATE.memo("process", maxsize=64)
def _grime(kind: str, seed: int, size: int, counts: tuple[int, int, int] | None
           ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None, np.ndarray]:
    """The floor's stains, smears and cracks (None without grime) and its puddles' mask before wetness weighs it,
    drawn from the picture's random numbers after its first fields (`_start`), as `_floor` drew them; read-only."""
    rng = _rng(kind, seed)
    rng.bit_generator.state = _start(kind, seed, size, _floor_fields)[1]
    layers: list = [None, None, None]
    if counts is not None:
        stains_n, smears_n, cracks_n = counts
        layers = [_blobs(size, rng, stains_n, (0.03, 0.09)), _blobs(size, rng, smears_n, (0.015, 0.03), stretch=7.0),
                  _cracks(size, rng, cracks_n)]
    layers.append(np.clip((fbm(size, rng, octaves=4, base=2) + 0.15) * 4.0, 0.0, 1.0))
    for layer in layers:
        if layer is not None:
            layer.setflags(write=False)
    return tuple(layers)


def _wall(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """Paint with dirt: streaks running down from the slab, scuffs near the floor. v is height (world z).
    `tint` shifts the paint's brightness (the random level's other garages)."""
    grime = float(tex.param("grime", 0.5))
    paint, dirt = _wall_layers(tex.kind, tex.seed, size, float(tex.tile), float(tex.param("tint", 0.0)))
    shade = paint.copy()
    shade *= 1.0 - grime * dirt
    return _rgba(np.asarray(mat.color), np.clip(shade, 0.2, 1.3)), None


# A wide space draws the grime per scenario, and it only weighs a wall's dirt: the paint's shade and the dirt
# (streaks down from the slab, scuffs near the floor) are kept per picture, so that a wall is a weighted product
# (~1 ms at 512 px), not its layers made again, with the same pixels.
@STATE.memo("process", maxsize=64)
def _wall_layers(kind: str, seed: int, size: int, tile: float, tint: float) -> tuple[np.ndarray, np.ndarray]:
    """A wall's shade before its grime, and its dirt (what grime 1 takes off the shade), read-only: `_wall`
    weighs the dirt by the grime."""
    noise, streaks = _start(kind, seed, size, _wall_fields)[0]
    paint = (1.0 + tint) * (1.0 + 0.06 * noise)
    z = (np.arange(size, dtype=np.float32) / size * tile)[:, None]  # rows are world z, 0 at the floor
    streaks = np.clip(streaks, 0, 1)
    streaks = np.repeat(streaks.mean(axis=0, keepdims=True), size, axis=0)
    dirt = 0.25 * streaks * np.clip((z - 1.0) / 1.8, 0, 1) + 0.3 * np.exp(-z / 0.35)
    for layer in (paint, dirt):
        layer.setflags(write=False)
    return paint, dirt


def _stripes(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """Hazard stripes: the material's colour and near-black, diagonal, worn a little."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size * tex.tile
    band = ((xx + yy) / 0.2).astype(np.int32) % 2
    colour = np.where(band[..., None] == 0, np.asarray(mat.color[:3])[None, None], 0.02)
    noise, blobs = _started(tex, rng, size, _stripes_fields)
    shade = 1.0 + 0.1 * noise - 0.25 * float(tex.param("grime", 0.5)) * blobs
    rgb = np.clip(colour * shade[..., None], 0, 1)
    return np.concatenate([rgb, np.ones((size, size, 1))], axis=2).astype(np.float32), None


def _paint(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """Line paint worn through to the floor colour in patches, more where `wear` is higher."""
    wear = float(tex.param("wear", 0.3))
    floor = np.array([float(tex.param(f"floor_{c}", 0.1)) for c in "rgb"], np.float32)
    noise, grain = _started(tex, rng, size, _paint_fields)
    gone = np.clip((noise + 1.2 * wear - 0.85) * 5.0, 0.0, 1.0)
    kept, sheen = 1 - gone, 1.0 + 0.08 * grain
    paint = np.asarray(mat.color[:3], np.float32)
    # A channel at a time, into the picture (as _rgba): a wide space's draw wears every line's paint anew, and the
    # products broadcast over three channels took 2.1 ms at 192 px where this takes 0.1 (the same bytes).
    out, channel = np.empty((size, size, 4), np.float32), np.empty((size, size), np.float32)
    for k in range(3):
        np.multiply(kept, paint[k], out=channel)
        channel += floor[k] * gone
        channel *= sheen
        np.clip(channel, 0, 1, out=channel)
        out[..., k] = channel
    out[..., 3] = 1.0
    return out, None


def _ceiling(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """Cast concrete with formwork joints every 1.2 m and damp patches."""
    noise, damp = _started(tex, rng, size, _ceiling_fields)
    shade = 1.0 + 0.12 * noise - 0.2 * damp
    joints = (np.arange(size) / size * tex.tile) % 1.2 < 0.02
    shade[joints, :] *= 0.7
    shade[:, joints] *= 0.7
    return _rgba(np.asarray(mat.color), shade), None


def _shadow(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """A contact shadow: black, densest under the object's footprint (the decal's inner `core` fraction),
    fading to nothing at the decal's edge; `strength` is the darkest alpha. `shape`: box | round | edge
    (a wall's: dark at v = 0, fading with distance from the wall)."""
    core, strength = float(tex.param("core", 0.7)), float(tex.param("strength", 0.75))
    yy, xx = np.mgrid[-1:1:complex(0, size), -1:1:complex(0, size)].astype(np.float32)
    shape = tex.param("shape", "box")
    if shape == "round":
        d = np.sqrt(xx ** 2 + yy ** 2)
    elif shape == "edge":
        d = (yy + 1.0) / 2.0 * 1.0 / max(1e-3, 1.0 - core) + core  # yy = -1 is the wall
    else:
        cx, cy = float(tex.param("core_x", core)), float(tex.param("core_y", core))
        d = np.maximum(np.abs(xx) / max(cx, 1e-3), np.abs(yy) / max(cy, 1e-3)) * core
    fall = np.clip((1.0 - d) / max(1e-3, 1.0 - core), 0.0, 1.0)
    alpha = strength * np.where(d <= core, 1.0, fall ** 1.6)
    rgb = np.zeros((size, size, 3), np.float32)
    return np.concatenate([rgb, alpha[..., None]], axis=2).astype(np.float32), None


def _arrow(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """A painted floor arrow pointing along +x, worn like the lines."""
    import cv2

    a = np.zeros((size, size), np.uint8)
    s = size
    pts = np.array([[0.05, 0.42], [0.6, 0.42], [0.6, 0.25], [0.95, 0.5], [0.6, 0.75], [0.6, 0.58], [0.05, 0.58]])
    cv2.fillPoly(a, [(pts * s).astype(np.int32)], 255, cv2.LINE_AA)
    wear = float(tex.param("wear", 0.3))
    alpha = a.astype(np.float32) / 255.0 * np.clip(1.0 - wear * (0.6 + 0.6 * _started(tex, rng, s, _arrow_fields)[0]),
                                                   0, 1)
    rgb = np.broadcast_to(np.asarray(mat.color[:3], np.float32), (s, s, 3))
    return np.concatenate([rgb, alpha[..., None] * 0.9], axis=2).astype(np.float32), None


def _sign(mat: Material, tex: Texture, rng, size: int) -> tuple[np.ndarray, None]:
    """A sign face: the material's colour with white text (`text`), e.g. EXIT, B2, a bay number."""
    import cv2

    text = str(tex.param("text", "EXIT"))
    w, h = size * 2, size
    mask = np.zeros((h, w), np.uint8)
    scale = cv2.getFontScaleForHeight(cv2.FONT_HERSHEY_SIMPLEX, int(h * 0.55), 3) \
        if hasattr(cv2, "getFontScaleForHeight") else h / 40.0
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(2, h // 16))
    scale *= min(1.0, 0.85 * w / max(tw, 1))
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, max(2, h // 16))
    cv2.putText(mask, text, ((w - tw) // 2, (h + th) // 2), cv2.FONT_HERSHEY_SIMPLEX, scale, 255,
                max(2, h // 16), cv2.LINE_AA)
    ink = (mask.astype(np.float32) / 255.0)[..., None]
    if float(tex.param("clear", 0.0)):  # paint only: the text on a see-through ground (a decal)
        rgb = np.broadcast_to(np.asarray(mat.color[:3], np.float32), (h, w, 3))
        return np.concatenate([rgb, ink * 0.9], axis=2).astype(np.float32), None
    img = np.asarray(mat.color[:3], np.float32)[None, None] * (1 - ink) + 0.85 * ink
    return np.concatenate([img, np.ones((h, w, 1), np.float32)], axis=2), None


_MAKERS = {"concrete": _floor, "asphalt": _floor, "wall": _wall, "stripes": _stripes, "paint": _paint,
           "ceiling": _ceiling, "shadow": _shadow, "arrow": _arrow, "sign": _sign}
KINDS = tuple(_MAKERS)


# A scene of the research plan has ~96 textured materials (79 of them bay-number signs, ~0.5 MB each; ~64 MB in
# all): a cache of 48 was emptied in turn by every renderer load and glTF export, so each job drew every texture
# twice. 128 keeps one scene's.
TEXTURES_KEPT = 128


@STATE.memo("process", maxsize=TEXTURES_KEPT)
def image(material: Material) -> tuple[np.ndarray, np.ndarray | None]:
    """The material's texture as (linear RGBA float32 H x W x 4, roughness H x W or None). Cached: each made once
    per process (each replicate redraws eight)."""
    tex = material.texture
    if tex is None:
        raise GarageError("material has no texture", material.name)
    maker = _MAKERS.get(tex.kind)
    if maker is None:
        raise GarageError(f"unknown texture kind {tex.kind!r} ({' | '.join(KINDS)})", material.name)
    rgba, rough = maker(material, tex, _rng(tex.kind, tex.seed), _size(tex))
    return rgba, rough


@STATE.memo("process", maxsize=TEXTURES_KEPT)
def image8(material: Material) -> np.ndarray:
    """`srgb8` of the material's texture, read-only. Cached as `image` is: the renderer's load and the job's glTF
    export each asked for it at every job (~5 ms a texture, a tenth of a small job's time)."""
    out = srgb8(image(material)[0])
    out.setflags(write=False)
    return out


def srgb8(rgba: np.ndarray) -> np.ndarray:
    """Linear RGBA float -> 8-bit sRGB RGBA (for PNG and glTF). Each colour value goes through the same operations
    in the same precision as `np.where` of the curve's two branches computed them (the power on a contiguous array:
    numpy's vector loop), on the whole RGBA picture at once, the alpha then written over: a three-channel view of a
    four-channel picture costs a strided pass each (clip, copy back), more than the power on the alpha. A scenario
    of the wide space converts about ten pictures (9.4 -> 4.6 ms at 384 px on the Zen 3). The curve's linear
    branch is computed on the few values it takes (a garage's pictures hold hardly any so dark), not on the whole
    picture and copied where wanted: 2.6 -> 1.3 ms at 384 px on an Intel Xeon, the bytes equal to the code before
    on every float32 in [0, 1] (checked exhaustively). tests/test_look.py pins the bytes."""
    out = np.clip(rgba, 0, 1)
    low = out <= 0.0031308
    dark = out[low] if low.any() else None
    np.power(out, 1 / 2.4, out=out)
    out *= 1.055
    out -= 0.055
    if dark is not None:
        out[low] = dark * 12.92
    np.clip(rgba[..., 3], 0, 1, out=out[..., 3])
    out *= 255
    np.rint(out, out=out)
    return out.astype(np.uint8)
