"""A camera-sensor model applied to each rendered frame before detection.

A renderer's frame is noise-free however dark the scene: darkness alone barely moves YOLO's confidence. A real
camera counts photo-electrons, so a dark scene holds few of them; shot noise (Poisson) and read noise are then a
large part of the signal, and the auto-exposure's gain amplifies both. `SensorModel` reproduces that chain:

    8-bit sRGB render -> linear radiance -> (lens blur) -> expected electrons -> Poisson shot noise ->
    well saturation -> Gaussian read noise -> auto-exposure gain -> clipping -> sRGB -> 8 bits

Each RGB channel is treated as its own pixel (no Bayer mosaic or demosaicing), so the noise is per channel and
shows as colour speckle, much like a camera's raw chroma noise before denoising.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from garage_exp.core.errors import GarageError
from garage_exp.core.state import STATE
from garage_exp.core import arrays

# Sensor kinds (`sensor.kind`): name -> fn(model, frames, rng) -> the frames as the camera delivers them, frames
# (N, H, W, 3) uint8 numpy or torch. A kind is registered beside its function (`@register_sensor_kind`).
KINDS: dict[str, Callable] = {}
# Tone curves (`sensor.params.tone`): name -> fn(linear signal >= 0) -> display-linear signal (clipped at 1 after).
TONES: dict[str, Callable] = {}


def register_sensor_kind(name: str) -> Callable:
    """Register a sensor kind's function under `name` (see KINDS)."""
    def register(fn: Callable) -> Callable:
        KINDS[name] = fn
        return fn
    return register


def register_tone_curve(name: str) -> Callable:
    """Register a tone curve under `name` (see TONES)."""
    def register(fn: Callable) -> Callable:
        TONES[name] = fn
        return fn
    return register

# Parameter sets for conf/sensor/<name>.yaml (`kind` plus `params`).
LEVELS: dict[str, dict[str, Any]] = {
    "ideal": {"kind": "ideal", "params": {}},
    # A small automotive pixel (about 3 um: 6,000 e- full well, 3 e- read noise) whose AE reaches middle grey
    # with at most 16x gain. exposure 0.25: a rendered white collects 1,500 e-, about what a white wall lit at
    # ~100 lux gives such a pixel behind a colour filter (f/2, 33 ms, QE 0.6). A dim garage frame (linear
    # mean ~0.02) then holds ~30 e- per pixel on average: shot noise ~18%, amplified by the gain.
    "noisy": {"kind": "noisy", "params": {"full_well": 6000.0, "exposure": 0.25, "read_noise": 3.0,
                                          "target_brightness": 0.18, "max_gain": 16.0, "blur_sigma": 0.0,
                                          "quantize": True}},
}


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] to linear light (IEC 61966-2-1)."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v):
    """Linear light in [0, 1] to sRGB-encoded values (IEC 61966-2-1); numpy or torch."""
    v = v.clip(0.0, 1.0)
    return arrays.xp(v).where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1.0 / 2.4) - 0.055)


@register_tone_curve("srgb")
def no_tone(x):
    """No tone curve: the linear signal, clipped at full scale by the sRGB encoding."""
    return x


@register_tone_curve("filmic")
def aces(x):
    """Narkowicz's fit of the ACES filmic curve: linear in, display-linear out, 1.0 only at infinity."""
    return (x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14)


@STATE.memo("process", maxsize=8)
def _falloff(shape: tuple[int, int], strength: float) -> np.ndarray:
    h, w = shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx - (w - 1) / 2) ** 2 + (yy - (h - 1) / 2) ** 2) / (((w - 1) / 2) ** 2 + ((h - 1) / 2) ** 2)
    return (1.0 - strength * r2).astype(np.float32)


_OUT_STEPS, _OUT_RANGE = 16384, 4.0  # signal (full scale 1) -> output table: 1/4096 steps up to 4x full scale


@STATE.memo("process", maxsize=4)
def _output_table(tone: str, quantize: bool) -> np.ndarray:
    signal = TONES[tone]((np.arange(_OUT_STEPS, dtype=np.float64) + 0.5) * (_OUT_RANGE / _OUT_STEPS))
    out = linear_to_srgb(np.clip(signal, 0.0, 1.0))
    return np.rint(out * 255.0).astype(np.uint8) if quantize else out.astype(np.float32)


# uint8 -> linear as a table: 256 entries instead of a power per pixel.
_LINEAR_LUT = srgb_to_linear(np.arange(256, dtype=np.float64) / 255.0).astype(np.float32)


@dataclass(frozen=True)
class SensorModel:
    """A camera sensor with photon shot noise, read noise and auto-exposure (AE).

    name: the level's name (for logs), e.g. "noisy".
    kind: "ideal" returns the frame unchanged; "noisy" runs the sensor chain; "camera" runs it with shot noise
        drawn as a Gaussian of the same variance and the output from a table (6x faster, see `_fast`).
    full_well: electrons (e-) a pixel holds before it saturates. Together with `exposure` it sets how many
        electrons a scene yields, hence the shot-noise level (SNR of a pixel = sqrt(electrons)). Typical: 4,000
        to 10,000 e- for 2-3 um automotive pixels.
    exposure: the longest exposure the AE may use (exposure time x aperture x quantum efficiency), in units of
        the exposure at which a rendered linear radiance of 1.0 (white) exactly fills the well; dimensionless.
        exposure * full_well is the electron count of a rendered white at the longest exposure: the link between
        the renderer's arbitrary brightness and photons. Above 1, highlights saturate.
    read_noise: standard deviation of the readout noise in electrons (e- rms), added after the shot noise and
        amplified by the gain like the signal. Typical: 1.5 to 5 e-.
    target_brightness: the mean linear signal, as a fraction of full scale, the AE aims for; 0.18 is middle
        grey (about 118 of 255 once sRGB-encoded). Dimensionless, in (0, 1].
    max_gain: the largest gain (dimensionless, >= 1) the AE may apply once the exposure is at its longest;
        darker scenes stay darker than the target, as with a real camera.
    blur_sigma: standard deviation in pixels of a Gaussian lens/motion blur applied to the radiance before it
        reaches the sensor; 0 disables it.
    vignetting: the light lost in the image's corners, as a fraction (0: none; 0.35: a wide automotive lens),
        falling off with the squared distance from the centre (a cos^4 law's first term).
    tone: the tone curve before sRGB encoding: "srgb" (none: the linear signal clipped at full scale) or
        "filmic" (ACES's fitted curve: highlights roll off instead of clipping, so lamps and white cars keep
        their shape, as a camera's ISP tone map does).
    exposure_bias: the AE's exposure compensation in EV (stops): its target is target_brightness x 2^bias
        (capped at full scale), as a camera's exposure-bias setting shifts its metering; 0: none. In -4..4.
    quantize: True returns uint8 sRGB (the camera's 8-bit stream, as the detector gets it); False returns
        float32 sRGB in [0, 1], to study the noise without rounding.

    AE, like a converged camera AE metering the noise-free mean: when the longest exposure would overshoot the
    target, it shortens the exposure (fewer electrons, no gain); otherwise it keeps the longest exposure and
    raises the gain up to max_gain. The gain is what makes a dim scene visibly noisier than a bright one.
    """

    name: str = "ideal"
    kind: str = "ideal"
    full_well: float = 6000.0
    exposure: float = 0.25
    read_noise: float = 3.0
    target_brightness: float = 0.18
    max_gain: float = 16.0
    blur_sigma: float = 0.0
    quantize: bool = True
    vignetting: float = 0.0
    tone: str = "srgb"
    exposure_bias: float = 0.0

    def __post_init__(self) -> None:
        where = f"sensor.params ({self.name})"
        if self.kind not in KINDS:
            raise GarageError(f"unknown sensor kind {self.kind!r} ({' | '.join(KINDS)})", "sensor.kind")
        checks = [
            (self.full_well > 0, "full_well must be > 0 electrons"),
            (self.exposure > 0, "exposure must be > 0"),
            (self.read_noise >= 0, "read_noise must be >= 0 electrons"),
            (0 < self.target_brightness <= 1, "target_brightness must be in (0, 1]"),
            (self.max_gain >= 1, "max_gain must be >= 1"),
            (self.blur_sigma >= 0, "blur_sigma must be >= 0 pixels"),
            (0 <= self.vignetting < 1, "vignetting must be in [0, 1)"),
            (self.tone in TONES, f"tone must be one of {' | '.join(TONES)}"),
            (-4.0 <= self.exposure_bias <= 4.0, "exposure_bias must be in -4..4 EV"),
        ]
        for ok, message in checks:
            if not ok:
                raise GarageError(message, where)

    def exposure_and_gain(self, mean_linear: float) -> tuple[float, float]:
        """The AE's choice for a frame of mean linear radiance: (exposure used, gain)."""
        longest = mean_linear * self.exposure  # mean signal as a fraction of full scale at the longest exposure
        if longest <= 0:
            return self.exposure, self.max_gain
        needed = min(1.0, self.target_brightness * 2.0 ** self.exposure_bias) / longest
        if needed < 1.0:
            return self.exposure * needed, 1.0
        return self.exposure, min(needed, self.max_gain)

    def apply(self, rgb, rng):
        """The frame (H x W x 3 uint8, numpy or torch) as this camera would deliver it; `rng` draws the noise
        (same seed, same frame). A batch of one (`apply_batch`)."""
        if len(rgb.shape) != 3 or rgb.shape[2] != 3 or str(rgb.dtype).rsplit(".", 1)[-1] != "uint8":
            raise ValueError(f"expected an HxWx3 uint8 RGB frame, got {rgb.dtype} {tuple(rgb.shape)}")
        return KINDS[self.kind](self, rgb[None], rng)[0]

    def apply_batch(self, rgb, rng=None):
        """Frames (N, H, W, 3) uint8, numpy or torch (on their device), as this camera delivers them: uint8, or
        float32 with `quantize` off; each frame with its own auto-exposure. rng: a numpy Generator (its stream,
        whatever the frames' kind: a torch batch then draws the numbers a numpy batch would) or a torch Generator
        (None: torch's default). One rng draws the whole batch at once, which is not the stream of N `apply`
        calls."""
        if len(rgb.shape) != 4 or rgb.shape[-1] != 3 or str(rgb.dtype).rsplit(".", 1)[-1] != "uint8":
            raise ValueError(f"expected (N, H, W, 3) uint8 frames, got {rgb.dtype} {tuple(rgb.shape)}")
        return KINDS[self.kind](self, rgb, rng)

    def expose(self, rgb):
        """The radiance reaching the sensor ((N, H, W, 3) float32: sRGB decoded, lens blur, vignetting) and the
        AE's (exposure, gain) per frame: the front of every noisy kind's chain."""
        radiance = arrays.take(arrays.table(_LINEAR_LUT, rgb, ("linear",)), rgb)
        if self.blur_sigma > 0:
            radiance = arrays.gaussian_blur(radiance, self.blur_sigma)
        if self.vignetting > 0:
            shape = tuple(rgb.shape[1:3])
            falloff = arrays.table(_falloff(shape, self.vignetting), rgb, ("falloff", shape, self.vignetting))
            radiance = radiance * falloff[..., None]
        return radiance, [self.exposure_and_gain(m) for m in arrays.frame_means(radiance)]

    def deliver(self, signal):
        """The linear signal (full scale 1) through the tone curve and sRGB: float32 in [0, 1], or uint8."""
        out = arrays.cast(linear_to_srgb(TONES[self.tone](signal.clip(min=0.0)).clip(0.0, 1.0)), np.float32)
        return arrays.as_uint8(out * 255.0) if self.quantize else out

    def params(self) -> dict[str, Any]:
        """The parameters as logged with a run."""
        return asdict(self)


@register_sensor_kind("ideal")
def ideal(model: SensorModel, rgb, rng):
    """The frame as rendered."""
    return rgb


@register_sensor_kind("noisy")
def poisson_chain(model: SensorModel, rgb, rng):
    """The sensor chain: Poisson shot noise, well saturation, Gaussian read noise, gain, tone curve, sRGB."""
    radiance, chosen = model.expose(rgb)
    scale = arrays.column([e * model.full_well for e, _ in chosen], np.float64, radiance)
    expected = arrays.cast(radiance, np.float64) * scale
    electrons = arrays.cast(arrays.poisson(rng, expected).clip(max=model.full_well), np.float32)
    if model.read_noise > 0:
        electrons = electrons + arrays.normal(rng, model.read_noise, electrons)
    return model.deliver(electrons * arrays.column([g / model.full_well for _, g in chosen], np.float32, electrons))


@register_sensor_kind("camera")
def fast_chain(model: SensorModel, rgb, rng):
    """The "camera" kind's chain in float32 and tables: shot noise as a Gaussian of the Poisson's variance
    (within 1% of it above ~10 e-, where a frame's pixels are), read noise in the same draw, then the tone curve
    and sRGB as one lookup. About 10 ms a 640x480 frame instead of 60."""
    radiance, chosen = model.expose(rgb)
    expected = radiance * arrays.column([e * model.full_well for e, _ in chosen], np.float32, radiance)
    sd = arrays.xp(expected).sqrt(expected + np.float32(model.read_noise ** 2))
    electrons = expected + sd * arrays.standard_normal(rng, expected)
    gain = arrays.column([g / model.full_well for _, g in chosen], np.float32, expected)
    signal = electrons.clip(max=float(np.float32(model.full_well))) * gain
    index = arrays.as_int((signal * np.float32(_OUT_STEPS / _OUT_RANGE)).clip(0, _OUT_STEPS - 1))
    key = ("output", model.tone, model.quantize)
    return arrays.take(arrays.table(_output_table(model.tone, model.quantize), signal, key), index)


def make_sensor(*, name: str = "ideal", kind: str = "ideal", params: dict[str, Any] | None = None) -> SensorModel:
    """The default `sensor._target_`, called with the `sensor` group's keys: the model of that kind with its
    parameters, each checked (one GarageError naming `sensor.params.<key>`)."""
    params = dict(params or {})
    allowed = set(SensorModel.__dataclass_fields__) - {"name", "kind"}
    unknown = sorted(set(params) - allowed)
    if unknown:
        raise GarageError(f"unknown sensor parameter(s) {unknown}; allowed: {sorted(allowed)}", "sensor.params")
    for key, value in params.items():
        if key == "quantize":
            if not isinstance(value, bool):
                raise GarageError(f"quantize must be true or false, got {value!r}", "sensor.params.quantize")
        elif key == "tone":
            if value not in TONES:
                raise GarageError(f"tone must be one of {' | '.join(TONES)}, got {value!r}", "sensor.params.tone")
        elif isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)):
            raise GarageError(f"{key} must be a finite number, got {value!r}", f"sensor.params.{key}")
    return SensorModel(name=str(name), kind=str(kind), **params)
