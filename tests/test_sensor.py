import numpy as np
import pytest
from conftest import schema_node

from garage_exp.core.errors import GarageError
from garage_exp.perception.sensor import LEVELS, SensorModel, linear_to_srgb, make_sensor, srgb_to_linear


def noisy(**overrides) -> SensorModel:
    return make_sensor(**{"name": "noisy", "kind": "noisy", "params": {**LEVELS["noisy"]["params"], **overrides}})


def uniform(value: int, size: int = 64) -> np.ndarray:
    return np.full((size, size, 3), value, np.uint8)


def darken(rgb: np.ndarray, factor: float) -> np.ndarray:
    """The same scene with `factor` times less light (in linear radiance, as a real dimmer scene)."""
    return np.rint(linear_to_srgb(srgb_to_linear(rgb / 255.0) / factor) * 255).astype(np.uint8)


def linear_mean(rgb: np.ndarray) -> float:
    return float(srgb_to_linear(rgb / 255.0).mean())


def test_ideal_is_identity():
    rgb = np.random.default_rng(0).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    out = make_sensor(**LEVELS["ideal"]).apply(rgb, np.random.default_rng(1))
    assert np.array_equal(out, rgb)


def test_noisy_is_deterministic_for_a_seed():
    rgb = np.random.default_rng(0).integers(0, 256, (32, 48, 3), dtype=np.uint8)
    sensor = noisy()
    first = sensor.apply(rgb, np.random.default_rng(7))
    assert np.array_equal(first, sensor.apply(rgb, np.random.default_rng(7)))
    assert not np.array_equal(first, sensor.apply(rgb, np.random.default_rng(8)))


def test_output_is_uint8_of_the_same_shape():
    rgb = np.random.default_rng(0).integers(0, 256, (30, 40, 3), dtype=np.uint8)
    out = noisy(target_brightness=0.9).apply(rgb, np.random.default_rng(0))  # gain ~10: highlights clip
    assert out.dtype == np.uint8 and out.shape == rgb.shape
    assert out.max() == 255
    raw = noisy(quantize=False).apply(rgb, np.random.default_rng(0))
    assert raw.dtype == np.float32 and raw.min() >= 0.0 and raw.max() <= 1.0


def test_darkness_costs_signal_to_noise():
    bright = uniform(180)
    dark = darken(bright, 8)
    sensor = noisy(quantize=False)
    out_bright = sensor.apply(bright, np.random.default_rng(0))
    out_dark = sensor.apply(dark, np.random.default_rng(0))
    # Both reach the AE target (the gain is below its cap here), so the brightness is alike...
    assert abs(linear_mean(out_dark * 255) - linear_mean(out_bright * 255)) < 0.01
    # ...but the dark frame had 8x fewer electrons, amplified by 8x more gain: about sqrt(8) more noise.
    ratio = out_dark.std() / out_bright.std()
    assert 2.0 < ratio < 4.0, ratio


@pytest.mark.parametrize("value", [20, 60, 250])
def test_mean_brightness_moves_towards_the_target(value):
    sensor = noisy()
    rgb = uniform(value)
    before, after = linear_mean(rgb), linear_mean(sensor.apply(rgb, np.random.default_rng(0)))
    assert abs(after - sensor.target_brightness) < abs(before - sensor.target_brightness)


def test_gain_is_capped_and_bright_frames_shorten_the_exposure():
    sensor = noisy(max_gain=4.0)
    exposure, gain = sensor.exposure_and_gain(0.001)
    assert exposure == sensor.exposure and gain == 4.0
    exposure, gain = sensor.exposure_and_gain(0.9)  # brighter than the target at the longest exposure
    assert gain == 1.0 and exposure * 0.9 == pytest.approx(sensor.target_brightness)
    assert sensor.exposure_and_gain(0.0) == (sensor.exposure, 4.0)
    # A capped gain leaves a very dark frame darker than the target, as with a real camera.
    out = sensor.apply(uniform(3), np.random.default_rng(0))
    assert linear_mean(out) < 0.5 * sensor.target_brightness


def test_many_electrons_and_no_gain_reproduce_the_frame():
    """With a huge well, no read noise and AE at unit gain, the sensor chain must return the render itself:
    checks the sRGB <-> linear round trip and the electron scaling."""
    rgb = np.random.default_rng(3).integers(0, 256, (40, 40, 3), dtype=np.uint8)
    sensor = SensorModel("clean", "noisy", full_well=1e12, exposure=1.0, read_noise=0.0,
                         target_brightness=linear_mean(rgb))
    out = sensor.apply(rgb, np.random.default_rng(0))
    assert np.abs(out.astype(int) - rgb).max() <= 1


def test_read_noise_shows_in_black():
    black = uniform(0)
    assert noisy(read_noise=0.0).apply(black, np.random.default_rng(0)).max() == 0
    assert noisy(read_noise=5.0).apply(black, np.random.default_rng(0)).max() > 0


def test_blur_removes_fine_detail():
    checker = (np.indices((64, 64)).sum(axis=0) % 2 * 255).astype(np.uint8)
    rgb = np.repeat(checker[:, :, None], 3, axis=2)
    sharp = noisy(quantize=False).apply(rgb, np.random.default_rng(0))
    blurred = noisy(quantize=False, blur_sigma=1.5).apply(rgb, np.random.default_rng(0))
    assert np.abs(np.diff(blurred, axis=1)).mean() < 0.3 * np.abs(np.diff(sharp, axis=1)).mean()


def test_srgb_round_trip():
    v = np.linspace(0.0, 1.0, 1001)
    assert np.allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-9)
    assert srgb_to_linear(np.array([0.5]))[0] == pytest.approx(0.214, abs=1e-3)


@pytest.mark.parametrize("params, where", [
    ({"full_well": -1.0}, "sensor.params"),
    ({"max_gain": 0.5}, "sensor.params"),
    ({"target_brightness": 0.0}, "sensor.params"),
    ({"iso": 800}, "sensor.params"),
    ({"exposure": "long"}, "sensor.params.exposure"),
    ({"quantize": "yes"}, "sensor.params.quantize"),
])
def test_bad_parameters_raise_garage_error(params, where):
    with pytest.raises(GarageError) as err:
        make_sensor(**{"name": "bad", "kind": "noisy", "params": params})
    assert err.value.where.startswith(where)
    assert "\n" not in str(err.value)


def test_unknown_kind_and_config_objects():
    with pytest.raises(GarageError, match="sensor kind"):
        make_sensor(**{"name": "x", "kind": "thermal"})
    from omegaconf import OmegaConf

    from garage_exp.perception.schema import SensorConf

    conf = schema_node(SensorConf, {"name": "noisy", **LEVELS["noisy"]})
    from garage_exp.core.plugins import build

    sensor = build(conf, "a sensor model", "sensor._target_")  # as the job builds it: `_target_` and the keys
    assert sensor.kind == "noisy" and sensor.full_well == LEVELS["noisy"]["params"]["full_well"]
    assert build(OmegaConf.structured(SensorConf), "a sensor model", "sensor._target_").kind == "ideal"


@pytest.mark.parametrize("key, bad, good, message", [
    ("full_well", 0.0, 1e-3, "full_well must be > 0 electrons"),
    ("exposure", 0.0, 1e-3, "exposure must be > 0"),
    ("read_noise", -1e-3, 0.0, "read_noise must be >= 0 electrons"),
    ("target_brightness", 0.0, 1.0, "target_brightness must be in (0, 1]"),
    ("target_brightness", 1.001, 1e-3, "target_brightness must be in (0, 1]"),
    ("max_gain", 0.999, 1.0, "max_gain must be >= 1"),
    ("blur_sigma", -1e-3, 0.0, "blur_sigma must be >= 0 pixels"),
])
def test_each_range_check_at_its_boundary(key, bad, good, message):
    """The value just outside the range is refused with its own message naming the level; the boundary
    itself (or the nearest value inside) is accepted."""
    with pytest.raises(GarageError) as err:
        make_sensor(**{"name": "mine", "kind": "noisy", "params": {key: bad}})
    assert message in str(err.value) and err.value.where == "sensor.params (mine)"
    assert getattr(make_sensor(**{"name": "mine", "kind": "noisy", "params": {key: good}}), key) == good


def test_unknown_kind_message_lists_the_kinds():
    with pytest.raises(GarageError) as err:
        SensorModel(name="x", kind="thermal")
    assert "unknown sensor kind 'thermal' (ideal | noisy | camera)" in str(err.value) and err.value.where == "sensor.kind"


@pytest.mark.parametrize("value", [True, float("inf"), float("nan"), None, "1.0"])
def test_parameters_must_be_finite_numbers(value):
    with pytest.raises(GarageError) as err:
        make_sensor(**{"name": "n", "kind": "noisy", "params": {"read_noise": value}})
    assert f"read_noise must be a finite number, got {value!r}" in str(err.value)
    assert err.value.where == "sensor.params.read_noise"


def test_make_sensor_messages_and_defaults():
    with pytest.raises(GarageError) as err:
        make_sensor(**{"name": "n", "kind": "noisy", "params": {"iso": 800, "zoom": 2}})
    assert "unknown sensor parameter(s) ['iso', 'zoom']; allowed: ['blur_sigma', " in str(err.value)
    assert err.value.where == "sensor.params"
    with pytest.raises(GarageError) as err:
        make_sensor(**{"name": "n", "kind": "noisy", "params": {"quantize": 1}})
    assert "quantize must be true or false, got 1" in str(err.value)
    assert err.value.where == "sensor.params.quantize"
    plain = make_sensor()
    assert (plain.name, plain.kind) == ("ideal", "ideal") and plain.params() == SensorModel().params()
    ints = make_sensor(**{"name": "n", "kind": "noisy", "params": {"full_well": 5000, "quantize": False}})
    assert ints.full_well == 5000 and ints.quantize is False and ints.name == "n"
    assert make_sensor(**{"name": "n", "kind": "noisy", "params": None}).kind == "noisy"


def test_apply_refuses_frames_that_are_not_rgb_uint8():
    sensor = noisy()
    rng = np.random.default_rng(0)
    for frame in (np.zeros((4, 4), np.uint8), np.zeros((4, 4, 4), np.uint8), np.zeros((4, 4, 3), np.float32)):
        with pytest.raises(ValueError, match="expected an HxWx3 uint8 RGB frame"):
            sensor.apply(frame, rng)
    ideal = make_sensor(**{"kind": "ideal"})
    with pytest.raises(ValueError):
        ideal.apply(np.zeros((4, 4), np.uint8), rng)


def test_exposure_and_gain_values():
    s = noisy(exposure=0.25, target_brightness=0.18, max_gain=16.0)
    assert s.exposure_and_gain(0.0) == (0.25, 16.0)  # black: longest exposure, full gain
    exposure, gain = s.exposure_and_gain(1.44)  # 0.36 of full scale: half the exposure, no gain
    assert exposure == pytest.approx(0.125) and gain == 1.0
    exposure, gain = s.exposure_and_gain(0.36)  # 0.09: longest exposure, gain 2
    assert exposure == 0.25 and gain == pytest.approx(2.0)
    assert s.exposure_and_gain(0.72) == (0.25, 1.0)  # exactly on target
    assert s.exposure_and_gain(1e-6)[1] == 16.0  # capped


def test_unquantized_output_is_float_srgb_in_range():
    out = noisy(quantize=False).apply(uniform(100), np.random.default_rng(0))
    assert out.dtype == np.float32 and out.shape == (64, 64, 3)
    assert 0.0 <= out.min() and out.max() <= 1.0
    # The AE brings the uniform frame to its target (0.18 linear), sRGB-encoded, noise aside.
    assert float(out.mean()) == pytest.approx(float(linear_to_srgb(np.array([0.18]))[0]), abs=0.01)
