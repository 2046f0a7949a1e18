"""One resolver for the pixel sizes of real imagery: a folder's flag, the images' metadata, world files and
pixel_size.txt, the command's global option, the model's size; disagreements and malformed files are errors."""

import math

import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from meta_sim.core.errors import MetaSimError
from meta_sim.sim.pixelsize import (
    ImageFolder,
    PixelSize,
    assumed_warning,
    read_pixel_size_file,
    resolve_pixel_size,
    summary,
    summary_line,
    world_file_pixel_size_m,
)


def _png(path, px=8):
    spec = oiio.ImageSpec(px, px, 3, oiio.UINT8)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(np.zeros((px, px, 3), np.uint8))
    out.close()
    return path


def _exr(path, pixel_size_m):
    """An image whose own metadata states its pixel size, as a rendered tile's header does."""
    spec = oiio.ImageSpec(8, 8, 3, oiio.HALF)
    spec.attribute("metasim:pixel_size_m", str(pixel_size_m))
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(np.zeros((8, 8, 3), np.float32))
    out.close()
    return path


def test_a_folder_names_its_pixel_size_after_a_colon(tmp_path):
    folder = ImageFolder.parse(f"{tmp_path}/rio:0.5", "--real", fallback_m=0.3, fallback_flag="--real-gsd")
    assert (folder.path, folder.stated_m, folder.flag) == (tmp_path / "rio", 0.5, f"--real {tmp_path}/rio:METRES")
    assert ImageFolder.parse(tmp_path / "plain").stated_m is None
    odd = tmp_path / "scans:2"
    odd.mkdir()
    assert ImageFolder.parse(str(odd)) == ImageFolder(odd, flag=f"{odd}:METRES")  # a folder that exists is a path
    for text in ("rio:abc", "rio:0", "rio:-0.5", "rio:nan", "rio:inf", "rio:20", "rio:1_0", "rio:0.5m"):
        with pytest.raises(MetaSimError, match="the pixel size after ':' must be a number of metres per pixel"):
            ImageFolder.parse(text)
    with pytest.raises(MetaSimError, match="^--real-gsd: a pixel size must be from 0.01 to 10"):
        ImageFolder.parse("rio", "--real", fallback_m=float("nan"), fallback_flag="--real-gsd")


def test_pixel_size_txt_is_one_number_and_nothing_else(tmp_path):
    path = tmp_path / "pixel_size.txt"
    assert read_pixel_size_file(path) is None
    path.write_text("# OpenAerialMap, zoom 20\n\n  0.15  \n")
    assert read_pixel_size_file(path) == 0.15
    for text in ("", "abc", "0.5 0.6", "0.5\n0.6", "nan", "inf", "0.001", "20", "1_0", "0.5 # comment", "-0.5"):
        path.write_text(text)
        with pytest.raises(MetaSimError, match="must hold one number, the metres per pixel") as err:
            read_pixel_size_file(path)
        assert "\n" not in str(err.value) and str(path) in str(err.value)
    path.write_bytes(b"\xff\xfe0.5")
    with pytest.raises(MetaSimError, match="cannot be read as text"):
        read_pixel_size_file(path)
    path.write_text("0.5\n" + "#" * 5000)
    with pytest.raises(MetaSimError, match="not a small text file"):
        read_pixel_size_file(path)
    path.unlink()
    path.mkdir()
    with pytest.raises(MetaSimError, match="not a small text file"):
        read_pixel_size_file(path)


def test_world_files_are_read_strictly(tmp_path):
    png = _png(tmp_path / "ortho.png")
    assert world_file_pixel_size_m(png) is None
    world = tmp_path / "ortho.pgw"
    world.write_text("0.25\n0.0\n0.0\n-0.25\n500000.125\n4100000.125\n")
    assert world_file_pixel_size_m(png) == pytest.approx(0.25)
    (tmp_path / "ortho.prj").write_text('PROJCS["NAD83 / New York Long Island (ftUS)",GEOGCS["NAD83"],'
                                        'UNIT["US survey foot",0.3048006096012192]]')
    assert world_file_pixel_size_m(png) == pytest.approx(0.25 * 1200 / 3937)
    (tmp_path / "ortho.prj").write_text('GEOGCS["WGS 84",DATUM["WGS_1984"],UNIT["degree",0.0174532925199433]]')
    world.write_text("0.000003\n0\n0\n-0.000003\n32.6\n60.0\n")
    degree = math.pi * 6378137.0 / 180
    assert world_file_pixel_size_m(png) == pytest.approx(0.5 * (0.000003 * 0.5 + 0.000003) * degree, rel=1e-6)
    (tmp_path / "ortho.prj").unlink()
    bad = {"garbage\n": "holds six numbers", "0.25\n0\n0\n-0.25\n1\n": "holds six numbers",
           "0.25\n0\n0\n-0.25\n1\n2\n3\n": "holds six numbers", "0.25\n0\n0\n-0.25\n1\nnan\n": "holds six numbers",
           "0.25\n0.01\n0.01\n-0.25\n1\n2\n": "is rotated", "0.25\n0\n0\n-0.5\n1\n2\n": "not square",
           "0\n0\n0\n-0.25\n1\n2\n": "other than 0", "50\n0\n0\n-50\n1\n2\n": "outside 0.01-10 m"}
    for text, message in bad.items():
        world.write_text(text)
        with pytest.raises(MetaSimError, match=message) as err:
            world_file_pixel_size_m(png)
        assert str(world) in str(err.value) and "\n" not in str(err.value)
    world.unlink()
    (tmp_path / "ortho.wld").write_text("0.4 0 0 -0.4 10 20")  # the generic name, any whitespace
    assert world_file_pixel_size_m(png) == pytest.approx(0.4)


def test_the_first_way_that_states_a_size_wins_and_the_others_must_agree(tmp_path):
    png, exr = _png(tmp_path / "a.png"), _exr(tmp_path / "t.exr", 0.3)
    plain = ImageFolder(tmp_path, flag=f"--real {tmp_path}:METRES", fallback_flag="--real-gsd")
    with pytest.raises(MetaSimError, match=r"a.png: its pixel size is unknown; give its pixel size: --real .*:METRES, "
                                           r"a pixel_size.txt in .* or --real-gsd$"):
        resolve_pixel_size(png, plain)
    assert resolve_pixel_size(png, ImageFolder(tmp_path, fallback_m=0.5)) == PixelSize(0.5, "global option")
    assert resolve_pixel_size(png, ImageFolder(tmp_path, assumed_m=0.3)) == PixelSize(0.3, "assumed")
    assert resolve_pixel_size(exr, ImageFolder(tmp_path, fallback_m=0.5)) == PixelSize(0.3, "metadata")
    assert resolve_pixel_size(exr, ImageFolder(tmp_path, stated_m=0.31)) == PixelSize(0.31, "flag")  # they agree
    with pytest.raises(MetaSimError, match=r"t.exr: --real .*:0.5 says 0.5 m per pixel but its own metadata says "
                                           r"0.3; correct or remove --real .*:0.5$"):
        resolve_pixel_size(exr, ImageFolder(tmp_path, 0.5, f"--real {tmp_path}:METRES"))
    (tmp_path / "pixel_size.txt").write_text("0.15\n")
    assert resolve_pixel_size(png, ImageFolder(tmp_path, fallback_m=0.5)) == PixelSize(0.15, "pixel_size.txt")
    assert resolve_pixel_size(png, ImageFolder(tmp_path, stated_m=0.15)) == PixelSize(0.15, "flag")
    with pytest.raises(MetaSimError, match=r"its own metadata says 0.3 m per pixel but .*pixel_size.txt says 0.15; "
                                           r"correct or remove .*pixel_size.txt$"):
        resolve_pixel_size(exr, ImageFolder(tmp_path))
    (tmp_path / "a.pgw").write_text("0.155 0 0 -0.155 0 0")  # within a few per cent of pixel_size.txt
    assert resolve_pixel_size(png, ImageFolder(tmp_path)) == PixelSize(0.155, "world file")
    (tmp_path / "a.pgw").write_text("0.5 0 0 -0.5 0 0")
    with pytest.raises(MetaSimError, match=r"a.pgw says 0.5 m per pixel but .*pixel_size.txt says 0.15; correct or "
                                           r"remove .*a.pgw or .*pixel_size.txt$"):
        resolve_pixel_size(png, ImageFolder(tmp_path))
    (tmp_path / "pixel_size.txt").write_text("fifteen centimetres")
    with pytest.raises(MetaSimError, match="must hold one number"):  # malformed: an error even where a flag wins
        resolve_pixel_size(png, ImageFolder(tmp_path, stated_m=0.5))


def test_reports_say_what_stated_each_size_and_warn_once_for_the_assumed():
    folder = ImageFolder("targets", flag="targets:METRES", fallback_flag="--gsd", assumed_m=0.3)
    sizes = [PixelSize(0.3, "assumed"), PixelSize(0.5, "metadata"), PixelSize(0.3, "assumed")]
    assert summary(sizes) == [{"pixel_size_m": 0.5, "source": "metadata", "stated": True, "images": 1},
                              {"pixel_size_m": 0.3, "source": "assumed", "stated": False, "images": 2}]
    assert summary_line(summary(sizes)) == ("0.5 m per pixel (stated by metadata) for 1 image; "
                                            "0.3 m per pixel (assumed) for 2 images")
    assert assumed_warning(folder, sizes) == (
        "warning: 2 of 3 images in targets do not state their pixel size; taken as the model's 0.3 m. State it: "
        "targets:METRES, a pixel_size.txt in targets or --gsd")
    assert assumed_warning(folder, sizes[1:2]) is None


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=st.binary(max_size=80) | st.text(max_size=80)
       | st.lists(st.floats(allow_nan=True, allow_infinity=True).map(repr) | st.text(max_size=4), max_size=8)
       .map("\n".join))
def test_files_beside_the_images_give_a_size_in_range_or_one_error(tmp_path, content):
    png = tmp_path / "a.png"
    if not png.exists():
        _png(png)
    readers = {"pixel_size.txt": lambda: read_pixel_size_file(tmp_path / "pixel_size.txt"),
               "a.pgw": lambda: world_file_pixel_size_m(png)}
    for name, read in readers.items():
        (tmp_path / name).write_bytes(content if isinstance(content, bytes) else content.encode())
        try:
            metres = read()
        except MetaSimError as exc:
            assert "\n" not in str(exc)
            continue
        assert metres is not None and 0.01 <= metres <= 10
