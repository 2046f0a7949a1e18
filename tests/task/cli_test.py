"""`meta-sim task train | eval` on real image/mask folders and rendered tiles."""

import json

import numpy as np
import torch
from click.testing import CliRunner

from meta_sim.cli import main
from meta_sim.sim import tiles
from meta_sim.sim.textures.pngio import write_png
from meta_sim.task.unet import load_segmenter

TINY = ["--steps", "3", "--batch", "4", "--crop", "32", "--width", "8", "--depth", "3"]


def _real(folder, n=3, px=64):
    rng = np.random.default_rng(0)
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    for k in range(n):
        mask = np.zeros((px, px), np.uint8)
        mask[10:30, 12:40] = 255
        image = (rng.random((px, px, 3)) * 120).astype(np.uint8)
        image[mask > 0] = (200, 90, 60)
        write_png(folder / "images" / f"r{k}.png", image)
        write_png(folder / "masks" / f"r{k}.png", np.repeat(mask[:, :, None], 3, axis=2))
    return folder


def _rendered(folder, n=2, px=96):
    folder.mkdir()
    rng = np.random.default_rng(1)
    for k in range(n):
        instance = np.zeros((px, px), np.uint32)
        instance[20:50, 30:70] = 1
        meta = tiles.tile_metadata(design={"flat_roof": "f"}, space="toy", city_seed=k, tile_index=0,
                                   origin_m=(0, 0), size_px=(px, px), pixel_size_m=0.3, preset="fast")
        tiles.write_tile(folder / f"d{k:05d}_t00.exr", rng.random((px, px, 3)).astype(np.float32), instance,
                         instance.copy(), meta)
    return folder


def test_train_then_eval_on_real_and_rendered_folders(tmp_path):
    real, rendered = _real(tmp_path / "real"), _rendered(tmp_path / "rendered")
    runner = CliRunner()
    args = ["task", "train", "--real", str(real), "--real-gsd", "0.3", "--synthetic", str(rendered), *TINY,
            "--mix", "3:1", "--seed", "5"]
    first = runner.invoke(main, [*args, "--out", str(tmp_path / "a.pt")])
    assert first.exit_code == 0, first.output
    assert "3 real + 1 synthetic crops" in first.output
    assert runner.invoke(main, [*args, "--out", str(tmp_path / "b.pt")]).exit_code == 0
    a, b = load_segmenter(tmp_path / "a.pt"), load_segmenter(tmp_path / "b.pt")
    assert all(torch.equal(x, y) for x, y in zip(a.model.state_dict().values(), b.model.state_dict().values()))
    assert a.training["real"]["images"] == 3 and a.training["synthetic"]["images"] == 2

    for labelled in (real, rendered):
        out = tmp_path / f"eval-{labelled.name}"
        result = runner.invoke(main, ["task", "eval", str(tmp_path / "a.pt"), str(labelled), "--real-gsd", "0.3",
                                      "--out", str(out)])
        assert result.exit_code == 0, result.output
        scores = json.loads((out / "scores.json").read_text())
        assert 0 <= scores["iou"] <= 1 and len(scores["per_image"]) in (2, 3)
        assert (out / "predictions.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert "IoU" in result.output

    # the encoder plug-in: a second model starts from the first one's encoder
    plugged = runner.invoke(main, ["task", "train", "--real", str(real), "--real-gsd", "0.3", *TINY,
                                   "--steps", "1", "--encoder", str(tmp_path / "a.pt"),
                                   "--out", str(tmp_path / "c.pt")])
    assert plugged.exit_code == 0, plugged.output
    # the scene colour augmentation, for training on renders, is recorded with the model
    scene = runner.invoke(main, ["task", "train", "--synthetic", str(rendered), *TINY, "--steps", "2",
                                 "--colour-augment", "scene", "--out", str(tmp_path / "d.pt")])
    assert scene.exit_code == 0, scene.output
    assert load_segmenter(tmp_path / "d.pt").training["colour"] == "scene" and a.training["colour"] == "light"
    # the command offers every augmentation the training knows
    from meta_sim.cli.task import train_command
    from meta_sim.task.data import COLOUR_AUGMENTS

    option = next(p for p in train_command.params if p.name == "colour_augment")
    assert tuple(option.type.choices) == COLOUR_AUGMENTS


def test_bad_task_command_lines_fail_cleanly(tmp_path):
    real = _real(tmp_path / "real")
    runner = CliRunner()
    cases = [
        (["task", "train", "--out", str(tmp_path / "x.pt")], "--real and/or --synthetic"),
        (["task", "train", "--real", str(tmp_path / "nowhere"), "--out", str(tmp_path / "x.pt")], "images/ and masks/"),
        (["task", "train", "--real", str(real), "--crop", "30", "--out", str(tmp_path / "x.pt")], "multiple of 8"),
        (["task", "train", "--real", str(real), "--out", str(tmp_path / "x.pt")], "pixel size is unknown"),
        (["task", "train", "--real", str(real), "--synthetic", str(real), "--mix", "x",
          "--out", str(tmp_path / "x.pt")], "--mix"),
        (["task", "eval", str(tmp_path / "none.pt"), str(real), "--out", str(tmp_path / "e")], "not a file"),
        (["task", "train", "--real", str(real), "--colour-augment", "heavy", "--out", str(tmp_path / "x.pt")],
         "--colour-augment"),
    ]
    for args, message in cases:
        result = runner.invoke(main, args)
        assert result.exit_code == 2, (args, result.output)
        assert message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "x.pt").exists()


def test_each_real_folder_is_read_at_the_pixel_size_it_states(tmp_path):
    from meta_sim.sim.pixelsize import ImageFolder
    from meta_sim.task.data import real_pool

    by_file, by_world, by_flag = (_real(tmp_path / name) for name in ("by_file", "by_world", "by_flag"))
    (by_file / "pixel_size.txt").write_text("# metres per pixel\n0.3\n")
    for image in (by_world / "images").glob("*.png"):
        image.with_suffix(".pgw").write_text("0.15\n0\n0\n-0.15\n500000\n4100000\n")
    given = [str(by_file), str(by_world), f"{by_flag}:0.6"]
    pools = [real_pool(ImageFolder.parse(text, "--real", fallback_m=1.2), 0.6) for text in given]
    # 64 px at 0.3, 0.15 and 0.6 m, each brought to 0.6 m: resampled by a half, a quarter and not at all
    assert [p.images[0].shape for p in pools] == [(32, 32, 3), (16, 16, 3), (64, 64, 3)]
    assert [p.masks[0].sum() for p in pools] == [140, 28, 560]  # the 20 x 28 px building at each scale (edges halved)
    assert [(s.metres, s.source) for s in (p.own_sizes[0] for p in pools)] == [
        (0.3, "pixel_size.txt"), (0.15, "world file"), (0.6, "flag")]

    result = CliRunner().invoke(main, ["task", "train", *[a for text in given for a in ("--real", text)],
                                       "--real-gsd", "1.2", *TINY, "--out", str(tmp_path / "m.pt")])
    assert result.exit_code == 0, result.output
    assert f"{by_file}: 0.3 m per pixel (stated by pixel_size.txt) for 3 images" in result.stdout
    assert f"{by_world}: 0.15 m per pixel (stated by world file) for 3 images" in result.stdout
    assert f"{by_flag}: 0.6 m per pixel (stated by flag) for 3 images" in result.stdout


def test_bad_pixel_sizes_are_one_line_errors_naming_the_fix(tmp_path):
    real, odd = _real(tmp_path / "real"), _real(tmp_path / "odd")
    (odd / "pixel_size.txt").write_text("about half a metre\n")
    out = ["--out", str(tmp_path / "x.pt")]
    cases = [
        (["--real", str(real)], f"give its pixel size: --real {real}:METRES, a pixel_size.txt in {real} or --real-gsd"),
        (["--real", f"{real}:zero"], "the pixel size after ':' must be a number of metres per pixel"),
        (["--real", f"{real}:50"], "the pixel size after ':' must be a number of metres per pixel"),
        (["--real", str(real), "--real-gsd", "-1"], "--real-gsd: a pixel size must be from 0.01 to 10"),
        (["--real", f"{real}:0.3", "--real", str(odd)], f"{odd / 'pixel_size.txt'} must hold one number"),
    ]
    for args, message in cases:
        result = CliRunner().invoke(main, ["task", "train", *args, *TINY, *out])
        assert result.exit_code == 2, (args, result.output)
        assert result.output.count("\n") == 1 and message in result.output and "Traceback" not in result.output
    (odd / "pixel_size.txt").unlink()
    (odd / "images" / "r0.pgw").write_text("0.3\n0\n0\n-0.6\n0\n0\n")
    result = CliRunner().invoke(main, ["task", "train", "--real", str(odd), *TINY, *out])
    assert result.exit_code == 2 and "r0.pgw: its pixels are not square (0.3 by 0.6); correct or remove it" \
        in result.output
    assert not (tmp_path / "x.pt").exists()


def test_eval_records_the_pixel_sizes_and_warns_once_when_it_assumes_them(tmp_path):
    real, rendered = _real(tmp_path / "real"), _rendered(tmp_path / "rendered")
    runner = CliRunner()
    trained = runner.invoke(main, ["task", "train", "--real", f"{real}:0.3", *TINY, "--steps", "1",
                                   "--gsd", "0.3", "--out", str(tmp_path / "m.pt")])
    assert trained.exit_code == 0, trained.output
    assumed = runner.invoke(main, ["task", "eval", str(tmp_path / "m.pt"), str(real), "--out", str(tmp_path / "a")])
    assert assumed.exit_code == 0, assumed.output
    warnings = [line for line in assumed.stderr.splitlines() if line.startswith("warning:")]
    assert warnings == [f"warning: 3 of 3 images in {real} do not state their pixel size; taken as the model's 0.3 m. "
                        f"State it: {real}:METRES, a pixel_size.txt in {real} or --real-gsd"]
    scores = json.loads((tmp_path / "a" / "scores.json").read_text())
    assert scores["pixel_sizes"] == {str(real): [{"pixel_size_m": 0.3, "source": "assumed", "stated": False,
                                                  "images": 3}]}
    stated = runner.invoke(main, ["task", "eval", str(tmp_path / "m.pt"), f"{real}:0.15", "--out", str(tmp_path / "s")])
    assert stated.exit_code == 0 and "warning" not in stated.output
    scores = json.loads((tmp_path / "s" / "scores.json").read_text())
    assert scores["pixel_sizes"][str(real)] == [{"pixel_size_m": 0.15, "source": "flag", "stated": True, "images": 3}]
    tiles = runner.invoke(main, ["task", "eval", str(tmp_path / "m.pt"), str(rendered), "--out", str(tmp_path / "t")])
    assert json.loads((tmp_path / "t" / "scores.json").read_text())["pixel_sizes"][str(rendered)] == [
        {"pixel_size_m": 0.3, "source": "metadata", "stated": True, "images": 2}] and "warning" not in tiles.output
    refused = runner.invoke(main, ["task", "eval", str(tmp_path / "m.pt"), f"{rendered}:0.3", "--out",
                                   str(tmp_path / "r")])
    assert refused.exit_code == 2 and "carry their pixel size; drop the :0.3" in refused.output


def test_task_commands_refuse_before_training_and_leave_no_folder_behind(tmp_path):
    real, rendered = _real(tmp_path / "real"), _rendered(tmp_path / "rendered")
    (tmp_path / "models").mkdir()
    (tmp_path / "empty").mkdir()
    runner = CliRunner()
    train = ["task", "train", "--real", str(real), "--real-gsd", "0.3", *TINY]
    assert runner.invoke(main, [*train, "--out", str(tmp_path / "seg.pt")]).exit_code == 0
    before = sorted(tmp_path.rglob("*"))
    new = str(tmp_path / "new" / "out")
    cases = [
        ([*train, "--out", str(tmp_path / "models")], "is a folder"),
        ([*train, "--synthetic", str(rendered), "--mix", "6:0", "--out", new], "drop --synthetic"),
        ([*train, "--synthetic", str(rendered), "--mix", "0:1", "--out", new], "drop --real"),
        ([*train, "--synthetic", str(tmp_path / "empty"), "--out", new], "no rendered tiles"),  # fails reading
        (["task", "eval", str(tmp_path / "seg.pt"), str(tmp_path / "empty"), "--out", new], "images/ and masks/"),
    ]
    for args, message in cases:
        result = runner.invoke(main, args)
        assert result.exit_code == 2, (args, result.output)
        last = result.output.strip().splitlines()[-1]  # after any progress lines
        assert last.startswith("error: ") and message in last and "Traceback" not in result.output, result.output
        assert sorted(tmp_path.rglob("*")) == before, args
