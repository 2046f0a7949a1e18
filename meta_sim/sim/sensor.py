"""A camera after the renderer: what turns a clean linear render into an image like a real sensor's.

Blender renders scene-referred linear light; a real aerial or satellite image has gone through
optics, a sensor and an encoder. ``Sensor.apply`` models that chain on a rendered tile, in order:

1. colour balance: a gain per channel, and the exposure, on linear light;
2. haze: a share of the light replaced by a bluish airlight (atmospheric scattering);
3. optics: a Gaussian blur of ``blur_px`` pixels (the lens and motion blur of real imagery), then an
   unsharp mask of ``sharpen`` (the light plus that share of its difference to its blur of ``SHARPEN_PX``
   pixels: the sharpening of a survey camera's processing and of an orthomosaic resampled from a finer
   pixel, whose fine detail a rasterised render at the tile's own pixel lacks);
4. tone curve: linear up to ``knee``, then a shoulder that approaches ``ceiling`` (below white, room
   for the noise) without reaching it, so nothing clips and midtones keep their contrast. Workbench's
   light times the fast preset's exposure puts a white membrane roof near 1.7 and a plain sRGB
   encoding clips it flat; the shoulder keeps its texture;
5. sensor noise on the display values: read noise plus shot noise growing with brightness;
6. 8-bit quantisation and, with ``jpeg_quality``, a JPEG round trip (its blocks and ringing).

The result is stored as linear light again (the inverse sRGB curve of the display values), so every
reader of tiles sees the sensor's image through the same sRGB curve as before. Label passes are never
touched. Noise comes from a generator seeded by the tile (city seed, tile index), so the same tile
gets the same noise. The settings go into the tile's header (``metasim:sensor``).
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError
from .imageio import linear_to_srgb


@dataclass(frozen=True)
class Sensor:
    name: str = "none"
    exposure: float = 1.0
    gains: tuple[float, float, float] = (1.0, 1.0, 1.0)
    haze: float = 0.0  # share of airlight, 0..1
    airlight: tuple[float, float, float] = (0.55, 0.62, 0.72)  # linear colour of the haze
    blur_px: float = 0.0  # Gaussian sigma in pixels
    knee: float = 0.55  # linear value where the tone curve's shoulder starts
    ceiling: float = 0.86  # linear value the shoulder approaches (display 0.94: room for noise and JPEG)
    read_noise: float = 0.0  # standard deviation on display values (0..1)
    shot_noise: float = 0.0  # variance per unit of display value
    jpeg_quality: int = 0  # 0: no JPEG round trip
    sharpen: float = 0.0  # unsharp-mask amount (0: none), after the blur

    @property
    def active(self) -> bool:
        return self.name != "none"

    def check(self) -> Sensor:
        numbers = {"exposure": (self.exposure, 0.01, 100), "haze": (self.haze, 0, 1),
                   "blur_px": (self.blur_px, 0, 20), "knee": (self.knee, 0.05, 0.95),
                   "ceiling": (self.ceiling, 0.1, 1.0), "read_noise": (self.read_noise, 0, 0.5),
                   "shot_noise": (self.shot_noise, 0, 0.5), "sharpen": (self.sharpen, 0, 5)}
        for name, (value, low, high) in numbers.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
                raise MetaSimError(f"sensor {name} must be between {low} and {high}, not {value!r}")
        for name, triple in (("gains", self.gains), ("airlight", self.airlight)):
            if len(triple) != 3 or not all(isinstance(v, (int, float)) and 0 <= v <= 10 for v in triple):
                raise MetaSimError(f"sensor {name} must be three numbers from 0 to 10, not {triple!r}")
        if isinstance(self.jpeg_quality, bool) or self.jpeg_quality not in range(0, 101):
            raise MetaSimError(f"sensor jpeg_quality must be 0 (none) to 100, not {self.jpeg_quality!r}")
        return self

    def to_dict(self) -> dict:
        """The settings as plain values (a tile header's ``metasim:sensor``); ``sharpen`` only when set, so the
        headers of sensors without it, and the tiles cached with them, stay as they were."""
        out = {**asdict(self), "gains": list(self.gains), "airlight": list(self.airlight)}
        if not self.sharpen:
            del out["sharpen"]
        return out

    def apply(self, rgb: np.ndarray, seed) -> np.ndarray:
        """The sensor's image of the linear render ``rgb`` (H, W, 3), as linear float32."""
        if not self.active:
            return rgb
        light = np.clip(np.nan_to_num(rgb.astype(np.float32)), 0.0, None) * self.exposure
        light = light * np.asarray(self.gains, np.float32)
        if self.haze:
            light = (1.0 - self.haze) * light + self.haze * np.asarray(self.airlight, np.float32)
        if self.blur_px:
            light = gaussian_blur(light, self.blur_px)
        if self.sharpen:
            light = np.clip(light + self.sharpen * (light - gaussian_blur(light, SHARPEN_PX)), 0.0, None)
        display = linear_to_srgb(tone_curve(light, self.knee, self.ceiling), np.float32)
        if self.read_noise or self.shot_noise:
            rng = np.random.default_rng(seed)
            sigma = np.sqrt(self.read_noise ** 2 + self.shot_noise * display)
            display = display + sigma * rng.standard_normal(display.shape).astype(np.float32)
        display8 = np.clip(np.floor(display * 255.0 + 0.5), 0, 255).astype(np.uint8)
        if self.jpeg_quality:
            display8 = jpeg_round_trip(display8, self.jpeg_quality)
        return _DECODED[display8]  # ``_decode`` of each 8-bit level, looked up


SHARPEN_PX = 1.0  # the unsharp mask's Gaussian, in pixels


def fine_detail(display: np.ndarray) -> float:
    """How much detail an sRGB image holds at its finest scale: the standard deviation of its display brightness
    (the channels' mean) minus that brightness blurred by a Gaussian of one pixel. Sharpness, small texture and
    noise raise it; the blur of optics and resampling lowers it (``make bench-sensor`` fits the sensors by it)."""
    brightness = np.clip(display, 0.0, 1.0).mean(axis=2, keepdims=True).astype(np.float32)
    return float(np.std(brightness - gaussian_blur(brightness, 1.0)))


def tone_curve(light: np.ndarray, knee: float, ceiling: float = 1.0) -> np.ndarray:
    """Per channel: the identity up to ``knee``, then an exponential shoulder towards ``ceiling`` with
    the same slope at the knee (smooth, rising, below the ceiling for any finite light)."""
    if not 0 < knee < ceiling:
        raise MetaSimError(f"the tone curve's knee ({knee}) must lie between 0 and its ceiling ({ceiling})")
    x = np.clip(np.asarray(light, np.float32), 0.0, None)
    span = ceiling - knee
    above = x > knee  # only these reach the shoulder
    x[above] = knee + span * (1.0 - np.exp(-(x[above] - knee) / span))
    return x


def _decode(display: np.ndarray) -> np.ndarray:
    x = np.clip(display, 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(np.float32)


_DECODED = _decode(np.arange(256, dtype=np.float32) / 255.0)  # linear light of each 8-bit display level


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur of an (H, W, C) image, edges mirrored."""
    radius = max(1, int(np.ceil(3 * sigma)))
    taps = np.exp(-0.5 * (np.arange(-radius, radius + 1) / sigma) ** 2)
    taps = (taps / taps.sum()).astype(np.float32)
    out = image.astype(np.float32)
    for axis in (0, 1):
        pad = [(0, 0)] * out.ndim
        pad[axis] = (radius, radius)
        padded = np.pad(out, pad, mode="reflect" if out.shape[axis] > radius else "edge")
        out = sum(taps[k] * np.take(padded, np.arange(k, k + out.shape[axis]), axis=axis) for k in range(len(taps)))
    return out.astype(np.float32)


def jpeg_round_trip(display8: np.ndarray, quality: int) -> np.ndarray:
    """The 8-bit image after JPEG compression at ``quality`` and decoding (through OpenImageIO)."""
    import OpenImageIO as oiio

    with tempfile.TemporaryDirectory(prefix="meta-sim-jpeg-") as folder:
        path = str(Path(folder) / "tile.jpg")
        spec = oiio.ImageSpec(display8.shape[1], display8.shape[0], 3, oiio.UINT8)
        spec.attribute("Compression", f"jpeg:{int(quality)}")
        out = oiio.ImageOutput.create(path)
        if out is None or not out.open(path, spec) or not out.write_image(np.ascontiguousarray(display8)):
            raise MetaSimError(f"cannot JPEG-encode a tile: {oiio.geterror()}")
        out.close()
        image = oiio.ImageInput.open(path)
        if image is None:
            raise MetaSimError(f"cannot decode a JPEG tile: {oiio.geterror()}")
        try:
            pixels = image.read_image(0, 0, 0, 3, oiio.UINT8)
        finally:
            image.close()
    return np.asarray(pixels, dtype=np.uint8).reshape(display8.shape)


# Named sensors. "drone": a survey drone's orthomosaic (sharp, little noise, high-quality JPEG);
# "satellite": a pan-sharpened satellite image (softer optics, more noise, some haze, stronger JPEG,
# warmer balance). Their values were starting points set by eye against ../shared/realdata. "drone-v2" is
# "drone" with the sharpness `make bench-sensor` fits to the fine detail of the drone domains' adapt scenes
# (benchmarks/sensor.json: "drone" renders hold half of it); "drone" stays for the spaces and renders made with
# it. The same fit finds "satellite"'s blur already at Rio's.
SENSORS = {s.name: s for s in (
    Sensor(),
    Sensor("drone", blur_px=0.6, read_noise=0.008, shot_noise=0.0004, jpeg_quality=90),
    Sensor("drone-v2", blur_px=0.3, sharpen=0.25, read_noise=0.008, shot_noise=0.0004, jpeg_quality=90),
    Sensor("satellite", gains=(1.04, 1.0, 0.94), haze=0.06, blur_px=1.1, read_noise=0.015, shot_noise=0.001,
           jpeg_quality=80),
)}


def get_sensor(name: str | None) -> Sensor:
    """The named sensor ("none" or None: no sensor); MetaSimError listing the names for another."""
    if name is None:
        return SENSORS["none"]
    try:
        return SENSORS[name]
    except KeyError:
        raise MetaSimError(f"unknown sensor {name!r}; choose one of {', '.join(SENSORS)}") from None
