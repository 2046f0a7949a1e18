import math
import struct
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.sim import tiles
from meta_sim.sim.imageio import (
    cut_tiles,
    image_pixel_size_m,
    image_tiles,
    linear_to_srgb,
    list_images,
    load_targets,
    read_image,
    resample,
)
from meta_sim.sim.preview import to_srgb8

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"


def _write(path, pixels, fmt):
    pixels = np.ascontiguousarray(pixels if pixels.ndim == 3 else pixels[:, :, None])
    height, width, channels = pixels.shape
    spec = oiio.ImageSpec(width, height, channels, fmt)
    spec.attribute("oiio:UnassociatedAlpha", 1)  # store the values given, not un-premultiplied ones
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec), out.geterror()
    assert out.write_image(pixels), out.geterror()
    out.close()
    return path


def _tile(path, linear):
    height, width = linear.shape[:2]
    meta = tiles.tile_metadata(design={"flat_roof": "a"}, space="s", city_seed=1, tile_index=0, origin_m=(0, 0),
                               size_px=(width, height), pixel_size_m=0.3, preset="fast")
    zeros = np.zeros((height, width), np.uint32)
    tiles.write_tile(path, linear, zeros, zeros, meta)
    return path


@pytest.mark.parametrize("ext", ["png", "tif"])
@pytest.mark.parametrize("bits", [8, 16])
def test_grey_rgb_rgba_in_8_and_16_bits(tmp_path, ext, bits):
    rng = np.random.default_rng(bits)
    dtype, fmt, top = (np.uint8, oiio.UINT8, 255) if bits == 8 else (np.uint16, oiio.UINT16, 65535)
    values = rng.integers(0, top + 1, (20, 30, 4)).astype(dtype)
    expected = values.astype(np.float64) / top
    grey = read_image(_write(tmp_path / f"grey.{ext}", values[:, :, 0], fmt))
    assert grey.shape == (20, 30, 3) and grey.dtype == np.float32
    assert np.allclose(grey, expected[:, :, [0, 0, 0]], atol=1e-6)
    grey_alpha = read_image(_write(tmp_path / f"ga.{ext}", values[:, :, :2], fmt))
    assert np.allclose(grey_alpha, expected[:, :, [0, 0, 0]], atol=1e-6)
    rgb = read_image(_write(tmp_path / f"rgb.{ext}", values[:, :, :3], fmt))
    assert np.allclose(rgb, expected[:, :, :3], atol=1e-6)
    # Alpha is dropped and RGB is not premultiplied by it.
    rgba = read_image(_write(tmp_path / f"rgba.{ext}", values, fmt))
    assert np.allclose(rgba, expected[:, :, :3], atol=1e-6)


def test_jpeg_and_many_channels(tmp_path):
    smooth = np.linspace(0, 255, 40 * 40 * 3).reshape(40, 40, 3).astype(np.uint8)
    jpeg = read_image(_write(tmp_path / "a.jpg", smooth, oiio.UINT8))
    assert jpeg.shape == (40, 40, 3) and np.abs(jpeg - smooth / 255.0).max() < 0.05
    five = np.random.default_rng(0).random((8, 9, 5)).astype(np.float32)
    assert np.allclose(read_image(_write(tmp_path / "five.tif", five, oiio.FLOAT)), five[:, :, :3])


def test_float_tiff_is_display_referred_and_sanitised(tmp_path):
    values = np.array([[[0.5, 2.0, -1.0], [np.nan, np.inf, -np.inf]]], dtype=np.float32)
    out = read_image(_write(tmp_path / "f.tif", values, oiio.FLOAT))
    assert np.array_equal(out, np.array([[[0.5, 1.0, 0.0], [0.0, 1.0, 0.0]]], dtype=np.float32))


def test_exr_tile_is_linear_and_converted_to_srgb(tmp_path):
    linear = np.random.default_rng(2).random((24, 32, 3)).astype(np.float32)
    out = read_image(_tile(tmp_path / "t.exr", linear))
    half = linear.astype(np.float16).astype(np.float64)  # the tile stores half floats
    assert out.shape == (24, 32, 3) and out.dtype == np.float32
    assert np.allclose(out, linear_to_srgb(half), atol=1e-6)
    assert np.allclose(out[0, 0], [_srgb(v) for v in half[0, 0]], atol=1e-6)
    # The PNG previews use the same curve.
    assert np.array_equal(to_srgb8(half), np.floor(linear_to_srgb(half) * 255 + 0.5).astype(np.uint8))
    assert image_pixel_size_m(tmp_path / "t.exr") == 0.3


def _srgb(x):
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def test_nan_inf_and_hdr_exr_pixels_give_finite_unit_values(tmp_path):
    linear = np.array([[[np.nan, np.inf, -np.inf], [1e4, 65504.0, -3.0], [0.0, 1.0, 0.0031308]]], np.float32)
    out = read_image(_tile(tmp_path / "hdr.exr", linear))
    assert np.all(np.isfinite(out)) and out.min() >= 0.0 and out.max() <= 1.0
    assert np.allclose(out[0, :2], [[0, 1, 0], [1, 1, 0]])
    # A plain EXR with one Y channel is grey.
    grey = read_image(_write(tmp_path / "y.exr", np.full((4, 5), 0.5, np.float32), oiio.HALF))
    assert np.allclose(grey, _srgb(0.5), atol=1e-4) and grey.shape == (4, 5, 3)


def test_unreadable_files_raise_and_are_skipped_with_reasons(tmp_path):
    good = _write(tmp_path / "b_good.png", np.zeros((20, 20, 3), np.uint8), oiio.UINT8)
    exr = _tile(tmp_path / "a_tile.exr", np.zeros((20, 20, 3), np.float32))
    data = _write(tmp_path / "big.png", np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8),
                  oiio.UINT8).read_bytes()
    (tmp_path / "big.png").unlink()
    (tmp_path / "c_truncated.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "d_truncated.exr").write_bytes(exr.read_bytes()[: exr.stat().st_size // 2])
    (tmp_path / "e_empty.jpg").write_bytes(b"")
    (tmp_path / "f_notes.txt").write_text("not an image")
    (tmp_path / "g_fake.png").write_text("not a png either")
    (tmp_path / ".hidden.png").write_bytes(b"")
    (tmp_path / "subfolder").mkdir()
    paths, skipped = list_images(tmp_path)  # headers only: a PNG cut in half still has its header
    assert paths == [exr, good, tmp_path / "c_truncated.png"]
    reasons = {p.name: why for p, why in skipped}
    assert set(reasons) == {"d_truncated.exr", "e_empty.jpg", "f_notes.txt", "g_fake.png"}
    assert "truncated" in reasons["d_truncated.exr"]
    assert "empty" in reasons["e_empty.jpg"] and "not an image" in reasons["f_notes.txt"]
    for name in [*reasons, "c_truncated.png"]:
        with pytest.raises(MetaSimError, match=name):
            read_image(tmp_path / name)
    with pytest.raises(MetaSimError, match="truncated"):
        list(image_tiles(tmp_path / "c_truncated.png", 16))
    with pytest.raises(MetaSimError, match="no such file"):
        read_image(tmp_path / "missing.png")


def test_truncated_jpeg_is_caught(tmp_path):
    noisy = np.random.default_rng(1).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    data = _write(tmp_path / "a.jpg", noisy, oiio.UINT8).read_bytes()
    (tmp_path / "a.jpg").write_bytes(data[: len(data) // 2])
    with pytest.raises(MetaSimError, match="truncated"):
        read_image(tmp_path / "a.jpg")


def test_folder_without_images_says_so(tmp_path):
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(MetaSimError, match=r"no readable images in .*1 files skipped: a.txt"):
        list_images(tmp_path)
    with pytest.raises(MetaSimError, match="not a folder"):
        list_images(tmp_path / "a.txt")


def test_resample_shapes_and_values():
    img = np.random.default_rng(3).random((40, 60, 3)).astype(np.float32)
    assert resample(img, 0.3, 0.3) is img
    down = resample(img, 0.075, 0.3)
    assert down.shape == (10, 15, 3)
    assert np.allclose(down[0, 0], img[:4, :4].mean(axis=(0, 1)), atol=1e-6)  # exact 4x4 block mean
    assert resample(img, 0.5, 0.3).shape == (67, 100, 3)
    constant = np.full((13, 17, 3), 0.25, np.float32)
    for src in (0.1, 0.29, 0.45, 1.7):
        assert np.allclose(resample(constant, src, 0.3), 0.25, atol=1e-6)
    assert np.array_equal(resample(img, 0.2, 0.3), resample(img, 0.2, 0.3))
    for src, dst in ((1e-6, 0.3), (0.3, 1e-6)):
        with pytest.raises(MetaSimError, match="check the pixel size"):
            resample(img, src, dst)
    with pytest.raises(MetaSimError, match="positive"):
        resample(img, 0.0, 0.3)


def test_cut_tiles_shapes():
    def shapes(h, w, tile=100):
        return [t.shape[:2] for t in cut_tiles(np.zeros((h, w, 3), np.float32), tile)]

    assert shapes(80, 60) == [(80, 60)]
    assert shapes(200, 300) == [(100, 100)] * 6
    assert shapes(240, 120) == [(100, 100), (100, 100)]  # remainders of 40 and 20 < half a tile
    assert shapes(160, 250) == [(100, 100), (100, 100), (100, 50), (60, 100), (60, 100), (60, 50)]


def test_load_targets_resamples_by_metadata_and_gsd(tmp_path):
    tile = _tile(tmp_path / "t.exr", np.zeros((48, 64, 3), np.float32))
    png = _write(tmp_path / "p.png", np.zeros((100, 120, 3), np.uint8), oiio.UINT8)
    targets = load_targets([tile, png], tile_px=32)
    # 64x48 at 0.3 m: two full tiles and a 16 px strip; 120x100 (no pixel size): 3 rows of 3 + a 24 px remainder.
    assert [(p.name, t.shape) for p, t in targets] == [("t.exr", (32, 32, 3))] * 2 + [("t.exr", (16, 32, 3))] * 2 \
        + [("p.png", (32, 32, 3))] * 3 + [("p.png", (32, 24, 3))] + [("p.png", (32, 32, 3))] * 3 \
        + [("p.png", (32, 24, 3))] + [("p.png", (32, 32, 3))] * 3 + [("p.png", (32, 24, 3))]
    assert [t.shape for _, t in load_targets([png], tile_px=64, gsd=0.15)] == [(50, 60, 3)]
    with pytest.raises(MetaSimError, match="smaller than the 16 px minimum"):
        load_targets([png], tile_px=64, gsd=0.03)


def _ifd(entries, extra_at, next_ifd=0):
    """One TIFF IFD (little-endian): its entries, the next IFD's offset, then the values too long to
    stand in an entry, which are placed at ``extra_at``."""
    fmt = {3: "H", 4: "I", 12: "d"}
    out, extra = struct.pack("<H", len(entries)), b""
    for tag, kind, values in entries:
        raw = struct.pack(f"<{len(values)}{fmt[kind]}", *values)
        if len(raw) <= 4:
            out += struct.pack("<HHI", tag, kind, len(values)) + raw.ljust(4, b"\0")
        else:
            out += struct.pack("<HHII", tag, kind, len(values), extra_at + len(extra))
            extra += raw
    return out + struct.pack("<I", next_ifd) + extra


def _write_geotiff(path, scale, tiepoint, geokeys):
    """A minimal uncompressed 8-bit RGB GeoTIFF (OpenImageIO cannot write GeoTIFF tags)."""
    height, width = 6, 8
    pixels = bytes(height * width * 3)
    entries = [(256, 3, [width]), (257, 3, [height]), (258, 3, [8, 8, 8]), (259, 3, [1]), (262, 3, [2]),
               (273, 4, [0]), (277, 3, [3]), (278, 3, [height]), (279, 4, [len(pixels)]),
               (33550, 12, list(scale)), (33922, 12, list(tiepoint)),
               (34735, 3, [1, 1, 0, len(geokeys)] + [v for key, value in geokeys for v in (key, 0, 1, value)])]
    extra_at = 8 + 2 + 12 * len(entries) + 4
    data_at = len(b"II*\0" + struct.pack("<I", 8) + _ifd(entries, extra_at))
    entries = [(273, 4, [data_at]) if tag == 273 else (tag, kind, values) for tag, kind, values in entries]
    path.write_bytes(b"II*\0" + struct.pack("<I", 8) + _ifd(entries, extra_at) + pixels)
    return path


def test_geotiff_pixel_size(tmp_path):
    utm = _write_geotiff(tmp_path / "utm.tif", (0.5, 0.5, 0), (0, 0, 0, 5e5, 4e6, 0), [(1024, 1), (3072, 32633)])
    assert image_pixel_size_m(utm) == pytest.approx(0.5)
    assert read_image(utm).shape == (6, 8, 3)  # an ordinary image to OpenImageIO
    feet = _write_geotiff(tmp_path / "ft.tif", (1.0, 1.0, 0), (0, 0, 0, 0, 0, 0), [(1024, 1), (3076, 9002)])
    assert image_pixel_size_m(feet) == pytest.approx(0.3048)
    lat = 60.0
    northing = 6378137.0 * math.log(math.tan(math.pi / 4 + math.radians(lat) / 2))
    mercator = _write_geotiff(tmp_path / "wm.tif", (0.6, 0.6, 0), (0, 3, 0, 0, northing, 0),
                              [(1024, 1), (3072, 3857)])
    assert image_pixel_size_m(mercator) == pytest.approx(0.3, rel=1e-6)
    degrees = _write_geotiff(tmp_path / "deg.tif", (3e-6, 3e-6, 0), (0, 3, 0, 32.0, 0.0, 0), [(1024, 2)])
    assert image_pixel_size_m(degrees) == pytest.approx(3e-6 * math.pi * 6378137.0 / 180, rel=1e-6)
    state_plane = _write_geotiff(tmp_path / "sp.tif", (0.5, 0.5, 0), (0,) * 6, [(1024, 1), (3072, 2263)])
    assert image_pixel_size_m(state_plane) == pytest.approx(0.5 * 1200 / 3937)  # NY Long Island, US survey feet
    unknown_units = _write_geotiff(tmp_path / "u.tif", (1.0, 1.0, 0), (0,) * 6, [(1024, 1), (3076, 9036)])
    assert image_pixel_size_m(unknown_units) is None
    assert image_pixel_size_m(_write(tmp_path / "plain.tif", np.zeros((4, 4, 3), np.uint8), oiio.UINT8)) is None
    assert image_pixel_size_m(tmp_path / "missing.tif") is None


@pytest.mark.parametrize("pattern", ["kampala/ramp-data/sample_2/input/*.png", "rio/images/rio_img52.png"])
def test_real_photos(pattern):
    paths = sorted(REALDATA.glob(pattern))[:3]
    if not paths:
        pytest.skip(f"real imagery not found at {REALDATA / pattern} (shared/realdata is absent)")
    for path in paths:
        img = read_image(path)
        assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32
        assert np.all(np.isfinite(img)) and 0.0 <= img.min() and img.max() <= 1.0
        assert img.std() > 0.02  # a real photo, not a blank
        assert image_pixel_size_m(path) is None


@pytest.mark.parametrize("gsd", [None, 0.3, 0.15, 0.5, 0.71])
def test_a_large_image_read_in_windows_gives_the_tiles_of_a_whole_read(tmp_path, monkeypatch, gsd):
    from meta_sim.sim import imageio

    rng = np.random.default_rng(3)
    pixels = (rng.random((331, 277, 3)) * 255).astype(np.uint8)
    path = _write(tmp_path / "big.png", pixels, oiio.UINT8)
    whole = list(image_tiles(path, 64, gsd))
    monkeypatch.setattr(imageio, "MAX_WHOLE_PIXELS", 1000)  # every image is "large" now
    windowed = list(image_tiles(path, 64, gsd))
    assert [t.shape for t in windowed] == [t.shape for t in whole]
    assert max(float(np.abs(a - b).max()) for a, b in zip(windowed, whole)) < 1e-5
    with pytest.raises(MetaSimError, match="more than this reader takes whole"):
        read_image(path)


def test_world_files_and_pixel_size_txt_are_not_listed_as_images(tmp_path):
    png = _write(tmp_path / "ortho.png", np.zeros((40, 30, 3), np.uint8), oiio.UINT8)
    (tmp_path / "ortho.pgw").write_text("0.25\n0.0\n0.0\n-0.25\n500000.125\n4100000.125\n")
    tif = _write(tmp_path / "b.tif", np.zeros((20, 20, 3), np.uint8), oiio.UINT8)
    (tmp_path / "b.tfw").write_text("garbage\n")
    (tmp_path / "pixel_size.txt").write_text("0.25\n")
    assert image_pixel_size_m(png) is None  # world files are the resolver's (tests/sim/pixelsize_test.py)
    paths, skipped = list_images(tmp_path)
    assert paths == [tif, png] and skipped == []


def _geotiff_with_nodata(path, pixels, nodata: str):
    """A TIFF with GDAL's no-data tag (ASCII tag 42113), written by OpenImageIO and patched into its IFD."""
    _write(path, pixels, oiio.UINT8)
    import struct

    data = bytearray(path.read_bytes())
    order = "<" if data[:2] == b"II" else ">"
    ifd = struct.unpack(order + "I", data[4:8])[0]
    count = struct.unpack(order + "H", data[ifd:ifd + 2])[0]
    text = nodata.encode() + b"\0"
    if len(text) <= 4:  # a value of up to 4 bytes stands in the entry itself
        value = text.ljust(4, b"\0")
    else:
        value = struct.pack(order + "I", len(data))
        data += text
    entries = [data[ifd + 2 + 12 * i: ifd + 14 + 12 * i] for i in range(count)]
    entries.append(struct.pack(order + "HHI", 42113, 2, len(text)) + value)
    entries.sort(key=lambda e: struct.unpack(order + "H", bytes(e[:2]))[0])
    new_ifd = len(data)
    data += struct.pack(order + "H", len(entries)) + b"".join(bytes(e) for e in entries) + struct.pack(order + "I", 0)
    data[4:8] = struct.pack(order + "I", new_ifd)
    path.write_bytes(bytes(data))
    return path


def test_nodata_tiles_are_left_out_and_counted(tmp_path):
    pixels = np.full((64, 128, 3), 120, np.uint8)
    pixels[:, 64:] = 0  # the right half is the no-data value
    tif = _geotiff_with_nodata(tmp_path / "ortho.tif", pixels, "0")
    dropped = []
    tiles = list(image_tiles(tif, 64, dropped=dropped))
    assert len(tiles) == 1 and len(dropped) == 1 and tiles[0].shape == (64, 64, 3)
    assert np.allclose(tiles[0], 120 / 255)
    rgba = np.zeros((64, 128, 4), np.uint8)
    rgba[:, :, :3] = 90
    rgba[:, :64, 3] = 255  # the left half is opaque imagery, the right half transparent
    png = _write(tmp_path / "alpha.png", rgba, oiio.UINT8)
    dropped = []
    assert len(list(image_tiles(png, 64, dropped=dropped))) == 1 and len(dropped) == 1
    plain = _write(tmp_path / "plain.png", rgba[:, :, :3], oiio.UINT8)
    assert len(list(image_tiles(plain, 64))) == 2  # no alpha, no tag: every tile is imagery


@pytest.mark.parametrize("size", [16, 40, 200])
def test_a_large_photo_is_squared_in_bands_with_the_pixels_of_a_whole_read(tmp_path, monkeypatch, size):
    from meta_sim.sim import imageio
    from meta_sim.sim.imageio import read_rgb8_square

    pixels = (np.random.default_rng(5).random((97, 150, 3)) * 255).astype(np.uint8)
    path = _write(tmp_path / "photo.png", pixels, oiio.UINT8)
    whole = read_rgb8_square(path, size)
    monkeypatch.setattr(imageio, "MAX_WHOLE_PIXELS", 1000)
    banded = read_rgb8_square(path, size)
    assert whole.shape == banded.shape == (size, size, 3) and np.array_equal(whole, banded)


def _tiff_with_mask(path, rgb, imagery):
    """An 8-bit RGB TIFF with GDAL's internal mask: a second IFD, NewSubfileType 4, 1 bit per pixel."""
    height, width = imagery.shape
    pixels, bits = rgb.astype(np.uint8).tobytes(), np.packbits(imagery.astype(bool), axis=1).tobytes()

    first_at, entries = 8, 10
    second_at = first_at + 2 + 12 * entries + 4 + 6  # + BitsPerSample 8,8,8 stored after the first IFD
    pixels_at = second_at + 2 + 12 * entries + 4
    image = [(254, 4, [0]), (256, 3, [width]), (257, 3, [height]), (258, 3, [8, 8, 8]), (259, 3, [1]),
             (262, 3, [2]), (273, 4, [pixels_at]), (277, 3, [3]), (278, 3, [height]), (279, 4, [len(pixels)])]
    mask = [(254, 4, [4]), (256, 3, [width]), (257, 3, [height]), (258, 3, [1]), (259, 3, [1]), (262, 3, [4]),
            (273, 4, [pixels_at + len(pixels)]), (277, 3, [1]), (278, 3, [height]), (279, 4, [len(bits)])]
    path.write_bytes(b"II*\0" + struct.pack("<I", first_at) + _ifd(image, first_at + 2 + 12 * entries + 4, second_at)
                     + _ifd(mask, pixels_at) + pixels + bits)
    return path


def test_a_tiffs_internal_mask_leaves_out_the_tiles_it_hides(tmp_path, monkeypatch):
    from meta_sim.sim import imageio

    imagery = np.ones((64, 192), bool)
    imagery[:, 128:] = False  # the right third is masked out
    rgb = np.full((64, 192, 3), 100, np.uint8)
    tif = _tiff_with_mask(tmp_path / "masked.tif", rgb, imagery)
    dropped = []
    tiles = list(image_tiles(tif, 64, dropped=dropped))
    assert len(tiles) == 2 and len(dropped) == 1 and np.allclose(tiles[0], 100 / 255)
    monkeypatch.setattr(imageio, "MAX_WHOLE_PIXELS", 1000)  # read in windows: the same tiles
    dropped = []
    assert len(list(image_tiles(tif, 64, dropped=dropped))) == 2 and len(dropped) == 1


def test_specks_of_nodata_take_the_tiles_mean_imagery_colour(tmp_path):
    rgba = np.zeros((64, 64, 4), np.uint8)
    rgba[:, :, :3] = 90
    rgba[:, :, 3] = 255
    rgba[5:7, 5:7] = (255, 255, 255, 0)  # a 4-pixel hole stored white
    dropped = []
    (tile,) = image_tiles(_write(tmp_path / "speck.png", rgba, oiio.UINT8), 64, dropped=dropped)
    assert dropped == [] and np.allclose(tile, 90 / 255)  # the white never reaches the features
