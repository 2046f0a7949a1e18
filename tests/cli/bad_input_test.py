"""Every command checks its options before it reads, renders or writes anything.

Each row is a command line a user could type; each must exit 2 with one line on stderr, no
traceback, and leave no file behind.
"""

import pytest
from click.testing import CliRunner

from meta_sim.cli import main as cli

DESIGN = ["--design", "flat_roof=0,sloped_roof=0"]
SMALL = ["--tiles", "1", "--tile-px", "32", "--gsd", "1"]

BAD = [
    ("render", "--design", "flat_roof=²,sloped_roof=0", *SMALL, "--out", "{tmp}/out"),
    ("render", "--random-designs", "1", "--seed", "-1", *SMALL, "--out", "{tmp}/out"),
    ("render", *DESIGN, "--seed", "-1", *SMALL, "--out", "{tmp}/out"),
    ("render", *DESIGN, "--tiles", "1", "--tile-px", "100000", "--out", "{tmp}/out"),
    ("render", *DESIGN, "--tiles", "0", "--out", "{tmp}/out"),
    ("render", *DESIGN, *SMALL, "--gsd", "nan", "--out", "{tmp}/out"),
    ("render", "--random-designs", "0", *SMALL, "--out", "{tmp}/out"),
    ("render", *DESIGN, *SMALL, "--out", "/proc/meta-sim-nope"),
    ("render", *DESIGN, *SMALL, "--space", "{tmp}/missing.json", "--out", "{tmp}/out"),
    ("render", "--design", "flat_roof=0", *SMALL, "--out", "{tmp}/out"),
    ("textures", "build", "--size", "0", "--out", "{tmp}/bank"),
    ("textures", "build", "--size", "100000", "--out", "{tmp}/bank"),
    ("textures", "build", "--from", "{tmp}/no-photos", "--out", "{tmp}/bank"),
    ("textures", "build", "--from", "{tmp}/no-photos", "--out", "{tmp}/new/bank"),
    ("textures", "build", "--size", "16", "--out", "/proc/meta-sim-nope/bank"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/out", "--group-size", "0"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/out", "-S", "0"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/out", "-M", "0"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/out", "--gsd", "-1"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "/proc/meta-sim-nope/out"),
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/out"),  # no such model
    ("infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/new/out"),
    ("train", "--out", "/proc/meta-sim-nope", "--designs", "2", "--cache", "{tmp}/cache"),
    ("eval", "e1", "--out", "{tmp}/out", "--targets", "0", "--cache", "{tmp}/cache"),
    ("eval", "e1", "--out", "{tmp}/out", "-S", "5", "-M", "2", "--cache", "{tmp}/cache"),
    ("textures", "sheet", "--thumb", "0", "--out", "{tmp}/sheet.png"),
    ("textures", "sheet", "--thumb", "100000", "--out", "{tmp}/sheet.png"),
    ("textures", "sheet", "--out", "/proc/meta-sim-nope/sheet.png"),
    ("textures", "similarity", "--out", "/proc/meta-sim-nope/similarity.json"),
    ("dataset", "--designs", "0", "--cache", "{tmp}/cache"),
    ("dataset", "--cache", "/proc/meta-sim-nope"),
    ("train", "--out", "{tmp}/new/models", "--cache", "/proc/meta-sim-nope"),
    ("eval", "e1", "--out", "{tmp}/new/out", "--cache", "/proc/meta-sim-nope"),
    ("dataset", "--gsd", "-1", "--cache", "{tmp}/cache"),
    ("dataset", "--hidden", "0,-5", "--cache", "{tmp}/cache"),
    ("train", "--out", "{tmp}/models", "--max-epochs", "0", "--cache", "{tmp}/cache"),
    ("train", "--out", "{tmp}/models", "--roof-finder-steps", "0", "--cache", "{tmp}/cache"),
    ("train", "--out", "{tmp}/models", "--roof-finder", "colour", "--roof-finder-steps", "500",
     "--cache", "{tmp}/cache"),
    ("eval", "e1", "--out", "{tmp}/out", "--dataset-seed", "-3", "--cache", "{tmp}/cache"),
    ("eval", "e1", "--out", "{tmp}/out", "--seed", "-1", "--cache", "{tmp}/cache"),
    ("eval", "e1", "--out", "{tmp}/out", "--split", "test", "--seed", "3", "--cache", "{tmp}/cache"),
    ("eval", "e2", "--out", "{tmp}/out", "--split", "test", "--targets", "1001", "--cache", "{tmp}/cache"),
    ("bench", "nams", "--targets", "0", "--no-docs", "--out", "{tmp}/nams.json", "--cache", "{tmp}/cache"),
    ("bench", "appearance", "--space", "overhead-v9", "--no-docs", "--out", "{tmp}/a.json", "--cache", "{tmp}/cache"),
    ("jobs", "plan", *DESIGN, "--tiles", "0", "--out", "{tmp}/job.json"),
    ("jobs", "status", "{tmp}/missing.json"),
    ("jobs", "run", "{tmp}/missing.json"),
    ("eval", "task", "e1", "--out", "{tmp}/out", "--seeds", "x", "--cache", "{tmp}/cache"),
    ("eval", "task", "e1", "--out", "{tmp}/out", "--steps", "0", "--cache", "{tmp}/cache"),
    ("eval", "task", "e3", "--out", "{tmp}/out", "--realdata", "{tmp}/nowhere", "--cache", "{tmp}/cache"),
    ("task", "train", "--real", "{tmp}/nowhere", "--out", "{tmp}/seg.pt"),
    ("task", "train", "--real", "{tmp}", "--steps", "0", "--out", "{tmp}/seg.pt"),
    ("task", "eval", "{tmp}/seg.pt", "{tmp}", "--out", "{tmp}/scores"),
    ("export", "{tmp}/no-tiles", "--out", "{tmp}/exported"),
    ("export", "{tmp}/no-tiles", "--out", "{tmp}/new/exported"),
]


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def _refused(tmp_path, args) -> str:
    """The one line a command refusing ``args`` prints, after checking it exits 2 and leaves no file."""
    before = _files(tmp_path)
    result = CliRunner().invoke(cli, [a.format(tmp=tmp_path) for a in args])
    assert result.exit_code == 2, (result.output, result.exception)
    assert isinstance(result.exception, SystemExit)  # no traceback
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(("error: ", "Error: ")), result.output
    assert _files(tmp_path) == before
    return lines[0]


@pytest.mark.parametrize("args", BAD, ids=[" ".join(a[:2]) + f" #{i}" for i, a in enumerate(BAD)])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(tmp_path, args, bank):
    _refused(tmp_path, args)  # with the default bank built (``bank``): its first build shows a progress line


# Command lines whose one line must name what fixes them.
NAMED = [
    (("render", *DESIGN, "--tiles", "1", "--tile-px", "96", "--out", "{tmp}/out"), "raise --tile-px or --gsd"),
    (("jobs", "plan", *DESIGN, "--tiles", "1", "--tile-px", "96", "--out", "{tmp}/job.json"),
     "raise --tile-px or --gsd"),
    (("jobs", "plan", *DESIGN, "--tiles", "64", "--tile-px", "4096", "--out", "{tmp}/job.json"),
     "lower --tile-px, --gsd or --tiles"),
    (("jobs", "plan", "--random-designs", "200000", "--out", "{tmp}/job.json"), "pass --yes"),
]


@pytest.mark.parametrize("args, fix", NAMED, ids=[" ".join(a[:2]) + f" #{i}" for i, (a, _) in enumerate(NAMED)])
def test_bad_input_names_its_fix(tmp_path, args, fix):
    assert fix in _refused(tmp_path, args)


def test_infer_into_a_folder_of_an_earlier_run_needs_overwrite(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "report.md").write_text("earlier run")
    result = CliRunner().invoke(cli, ["infer", str(tmp_path), "--model", str(tmp_path / "nams.pt"),
                                      "--out", str(tmp_path / "out")])
    assert result.exit_code == 2 and "--overwrite" in result.output
    assert (tmp_path / "out" / "report.md").read_text() == "earlier run"


def test_infer_into_a_file_says_so_even_with_overwrite(tmp_path):
    (tmp_path / "file").write_text("mine")
    args = ["infer", "{tmp}", "--model", "{tmp}/nams.pt", "--out", "{tmp}/file", "--overwrite"]
    assert "is a file" in _refused(tmp_path, args)
    assert (tmp_path / "file").read_text() == "mine"


def test_textures_build_into_a_file_or_a_folder_of_other_files_is_refused(tmp_path):
    (tmp_path / "file").write_text("mine")
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "holiday.jpg").write_text("mine")
    assert "is a file" in _refused(tmp_path, ["textures", "build", "--size", "16", "--out", "{tmp}/file"])
    assert "not a texture bank" in _refused(tmp_path, ["textures", "build", "--size", "16", "--out", "{tmp}/photos"])
    assert (tmp_path / "file").read_text() == "mine" and (tmp_path / "photos" / "holiday.jpg").read_text() == "mine"
