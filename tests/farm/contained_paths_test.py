"""Names from files that travel (manifests, design spaces, banks) never send a file outside its folder.

Each case replays an attack on the previous main: it wrote tiles wherever a manifest's task name or a
design space's choice id pointed, and a bank manifest could name any file as a texture.
"""

import json

import pytest
from click.testing import CliRunner

from meta_sim.cli import main as cli
from meta_sim.core.errors import MetaSimError
from meta_sim.core.names import inside, is_safe_name, safe_name
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.textures import load_bank

JOB = ["--random-designs", "2", "--seed", "3", "--cities", "1", "--tiles", "1", "--tile-px", "32", "--gsd", "3.6"]


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


@pytest.mark.parametrize("name", ["a/b", "..", ".hidden", "a\\b", "", "x" * 201, "a b", "é", "a\nb", 7, None])
def test_unsafe_names_are_refused(name):
    assert not is_safe_name(name)
    with pytest.raises(MetaSimError, match="not a safe name"):
        safe_name(name, "thing")


@pytest.mark.parametrize("name", ["flat-gravel-light", "d00001_t00.exr", "0.5+x_s-1", "-1", "a..b"])
def test_safe_names_pass(name):
    assert safe_name(name, "thing") == name


def test_inside_follows_links_out_of_the_folder(tmp_path):
    (tmp_path / "bank").mkdir()
    (tmp_path / "bank" / "link").symlink_to(tmp_path)
    assert inside(tmp_path / "bank", "a.png", "image") == (tmp_path / "bank" / "a.png").resolve()
    for escape in ("../a.png", "link/a.png", str(tmp_path / "a.png")):
        with pytest.raises(MetaSimError, match="outside its folder"):
            inside(tmp_path / "bank", escape, "image")


@pytest.mark.parametrize("hostile", ["{outside}/pwn", "../pwn", "..", ".pwn"])
def test_a_manifest_task_name_cannot_send_tiles_outside(tmp_path, hostile):
    outside = tmp_path / "outside"
    outside.mkdir()
    assert _cli("jobs", "plan", *JOB, "--out", tmp_path / "job.json").exit_code == 0
    data = json.loads((tmp_path / "job.json").read_text())
    data["tasks"][0]["name"] = hostile.format(outside=outside)
    data["tasks"][0]["outputs"] = [data["tasks"][0]["name"] + "_t00.exr"]
    (tmp_path / "job.json").write_text(json.dumps(data))
    for command in ("status", "run"):
        result = _cli("jobs", command, tmp_path / "job.json")
        assert result.exit_code == 2 and "not a safe name" in result.output, result.output
    assert _files(outside) == [] and not (tmp_path / "job-tiles").exists()


def test_a_manifest_task_must_match_its_content(tmp_path):
    assert _cli("jobs", "plan", *JOB, "--out", tmp_path / "job.json").exit_code == 0
    good = json.loads((tmp_path / "job.json").read_text())
    first = good["tasks"][0]
    edits = {
        "another name": {"name": "d0_s3_000000000000"},
        "another design": {"design": {**first["design"], "flat_roof": good["tasks"][1]["design"]["flat_roof"]}},
        "another city": {"city_seed": first["city_seed"] + 1},
        "a tile past n_tiles": {"tiles": [0, 1], "outputs": [f"{first['name']}_t00.exr", f"{first['name']}_t01.exr"]},
        "other outputs": {"outputs": ["elsewhere_t00.exr"]},
        "a bool seed": {"city_seed": True},
    }
    for what, edit in edits.items():
        data = json.loads(json.dumps(good))
        data["tasks"][0].update(edit)
        (tmp_path / "job.json").write_text(json.dumps(data))
        result = _cli("jobs", "status", tmp_path / "job.json")
        assert result.exit_code == 2 and result.output.startswith("error: "), (what, result.output)
        assert len(result.output.strip().splitlines()) == 1, (what, result.output)


@pytest.mark.parametrize("choice", ["{outside}/pwn", "../pwn", ".pwn"])
def test_a_design_space_choice_cannot_name_a_path(tmp_path, choice, bank):
    outside = tmp_path / "outside"
    outside.mkdir()
    space = DesignSpace.load().to_dict()
    space["parameters"][0]["choices"][0] = choice.format(outside=outside)
    (tmp_path / "space.json").write_text(json.dumps(space))
    result = _cli("render", "--space", tmp_path / "space.json", "--design", "flat_roof=0,sloped_roof=0",
                  "--tiles", "1", "--tile-px", "32", "--gsd", "3.6", "--out", tmp_path / "out")
    assert result.exit_code == 2 and "not a safe name" in result.output, result.output
    assert _files(outside) == [] and not (tmp_path / "out").exists()


def test_a_bank_texture_id_cannot_name_a_path(tmp_path, bank):
    manifest = json.loads((bank.root / "manifest.json").read_text())
    manifest["textures"][0]["id"] = "../../../../tmp/x/pwn"
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(MetaSimError, match="not a safe name"):
        load_bank(tmp_path)


def test_a_task_that_cannot_render_fails_alone_with_its_reason(tmp_path, capsys):
    from meta_sim.farm import manifest as farm
    from meta_sim.farm.worker import run_job

    assert _cli("jobs", "plan", *JOB, "--out", tmp_path / "job.json").exit_code == 0
    data = json.loads((tmp_path / "job.json").read_text())
    broken = data["tasks"][0]
    del broken["design"]["sloped_roof"]  # renamed consistently, as a hostile or buggy planner could
    shared = {"space": data["space"]["name"], "preset": data["preset"], "n_tiles": data["n_tiles"],
              "tile_px": data["tile_px"], "pixel_size_m": data["pixel_size_m"]}
    broken["name"] = farm.task_name(broken["design"], broken["city_seed"], shared)
    broken["outputs"] = [f"{broken['name']}_t00.exr"]
    (tmp_path / "job.json").write_text(json.dumps(data))
    failures = run_job(tmp_path / "job.json")
    assert [name for name, _ in failures] == [broken["name"]] and "lacks sloped_roof" in failures[0][1]
    assert (tmp_path / "job-tiles" / data["tasks"][1]["outputs"][0]).is_file()
    status = _cli("jobs", "status", tmp_path / "job.json")
    assert status.exit_code == 1 and "1 done, 1 missing" in status.output
