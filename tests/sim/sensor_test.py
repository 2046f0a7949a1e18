"""The sensor after the renderer: no clipping, deterministic noise, labels never touched, bad settings refused."""

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.imageio import linear_to_srgb
from meta_sim.sim.sensor import SENSORS, Sensor, gaussian_blur, get_sensor, jpeg_round_trip, tone_curve


def _scene(px=64, seed=0):
    """A white roof at 1.7 (as the fast preset renders one) on a textured lawn."""
    rng = np.random.default_rng(seed)
    rgb = (np.array([0.12, 0.2, 0.08]) * (1 + 0.2 * rng.standard_normal((px, px, 3)))).astype(np.float32)
    rgb[16:48, 16:48] = 1.7 * (1 + 0.05 * rng.standard_normal((32, 32, 3)))
    return rgb


def test_no_sensor_is_the_render_itself():
    rgb = _scene()
    assert get_sensor("none").apply(rgb, 1) is rgb and get_sensor(None) == Sensor()


@pytest.mark.parametrize("name", ["drone", "satellite"])
def test_sensors_keep_bright_roofs_below_white_and_midtones_as_they_were(name):
    rgb = _scene()
    out = SENSORS[name].apply(rgb, [3, 0])
    display = linear_to_srgb(out)
    roof = display[16:48, 16:48]
    assert float((roof.max(axis=2) >= 254.5 / 255).mean()) <= 0.01  # at most 1% of roof pixels clipped
    assert float((linear_to_srgb(rgb)[16:48, 16:48].max(axis=2) >= 254.5 / 255).mean()) == 1.0  # without it, all
    assert roof.std() > 0.005  # the roof keeps texture
    lawn_before, lawn_after = linear_to_srgb(rgb)[:12, :12].mean(), display[:12, :12].mean()
    assert abs(lawn_before - lawn_after) < 0.06  # below the knee the tone curve is the identity
    assert np.array_equal(out, SENSORS[name].apply(rgb, [3, 0]))  # the same tile, the same noise
    assert not np.array_equal(out, SENSORS[name].apply(rgb, [3, 1]))
    assert out.dtype == np.float32 and out.shape == rgb.shape and np.isfinite(out).all()


def test_tone_curve_is_smooth_rising_and_below_its_ceiling():
    x = np.linspace(0, 50, 20001, dtype=np.float32)
    y = tone_curve(x, 0.55, 0.9)
    assert np.all(np.diff(y) >= 0) and y.max() < 0.9 and np.array_equal(y[x <= 0.55], x[x <= 0.55])
    slope = np.diff(y) / np.diff(x)
    assert abs(slope[np.searchsorted(x, 0.55)] - 1.0) < 0.01  # no kink at the knee
    with pytest.raises(MetaSimError, match="knee"):
        tone_curve(x, 0.95, 0.9)


def test_the_sensors_float32_encoding_is_the_srgb_curve():
    """The display values the sensor adds its noise to: ``linear_to_srgb`` to float32 precision, NaN and the
    infinities included, and the input left as it was."""
    x = np.concatenate([np.linspace(-0.1, 1.2, 100001), [np.nan, np.inf, -np.inf, 0.0031308]]).astype(np.float32)
    kept = x.copy()
    out = linear_to_srgb(x, np.float32)
    assert out.dtype == np.float32 and np.array_equal(x, kept, equal_nan=True)
    assert np.abs(out - linear_to_srgb(x)).max() < 1e-6
    light = np.float32([0.2, 0.6, 3.0])
    assert np.array_equal(tone_curve(light, 0.55, 0.9)[:1], light[:1]) and light[1] == np.float32(0.6)


def test_blur_and_jpeg_keep_the_mean_and_change_the_detail():
    rgb = _scene()
    blurred = gaussian_blur(rgb, 1.5)
    assert abs(float(blurred.mean()) - float(rgb.mean())) < 0.01 and blurred.std() < rgb.std()
    image8 = (np.clip(linear_to_srgb(rgb), 0, 1) * 255).astype(np.uint8)
    jpeg = jpeg_round_trip(image8, 50)
    assert jpeg.shape == image8.shape and not np.array_equal(jpeg, image8)
    assert abs(float(jpeg.mean()) - float(image8.mean())) < 2.0


@pytest.mark.parametrize("bad", [dict(haze=2.0), dict(blur_px=-1), dict(jpeg_quality=101), dict(jpeg_quality=True),
                                 dict(gains=(1, 1)), dict(read_noise=float("nan")), dict(knee=0.99), dict(sharpen=-0.5),
                                 dict(sharpen=True)])
def test_bad_sensor_settings_are_refused(bad):
    with pytest.raises(MetaSimError, match="sensor"):
        Sensor(name="custom", **bad).check()


def test_named_sensors_are_valid_and_unknown_names_listed():
    for sensor in SENSORS.values():
        sensor.check()
    with pytest.raises(MetaSimError, match="none, drone, drone-v2, satellite"):
        get_sensor("xray")


def test_sharpening_raises_fine_detail_keeps_the_mean_and_stays_out_of_headers_when_unset():
    """The unsharp mask multiplies the finest detail (a one-pixel checkerboard's contrast grows), leaves a flat
    image and the mean alone, is applied after the blur, and is recorded in the header only when set (so the
    headers of the named sensors without it, and the tiles cached with them, are unchanged)."""
    checker = ((np.arange(32)[:, None] + np.arange(32)[None]) % 2).astype(np.float32) * 0.1 + 0.2
    rgb = np.repeat(checker[:, :, None], 3, axis=2)
    plain = Sensor(name="custom", knee=0.9, ceiling=1.0)
    sharp = Sensor(name="custom", knee=0.9, ceiling=1.0, sharpen=1.0)
    contrast = [float(np.std(s.apply(rgb, [0, 0]))) for s in (plain, sharp)]
    assert contrast[1] > 1.5 * contrast[0]
    assert float(np.mean(sharp.apply(rgb, [0, 0]))) == pytest.approx(float(np.mean(plain.apply(rgb, [0, 0]))), rel=0.03)
    flat = np.full((16, 16, 3), 0.3, np.float32)
    assert np.array_equal(sharp.apply(flat, [0, 0]), plain.apply(flat, [0, 0]))
    blurred_first = Sensor(name="custom", knee=0.9, ceiling=1.0, blur_px=2.0, sharpen=1.0).apply(rgb, [0, 0])
    assert float(np.std(blurred_first)) < 0.5 * contrast[0]  # the blur took the checkerboard first
    assert "sharpen" not in plain.to_dict() and sharp.to_dict()["sharpen"] == 1.0
    for sensor in SENSORS.values():
        assert ("sharpen" in sensor.to_dict()) == bool(sensor.sharpen)
