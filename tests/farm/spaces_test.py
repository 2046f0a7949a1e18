"""Every design space the package ships goes through every farm interface: plan, the local executor killed
and resumed, status, a shard through jobs/farm_shard.py, the Dask executor, the Flamenco export, and
`render --population` with a population in that space.

Designs of the richer spaces hold numbers and style ids besides roof ids: their manifests must survive the
save (sorted keys) and load of every interface. Tiles are tiny (48 px at 2.4 m/px) to keep real renders quick.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from toys import assert_same_tiles, job_pixels

from meta_sim.cli import main as cli
from meta_sim.core.errors import MetaSimError
from meta_sim.farm import executors
from meta_sim.farm import manifest as farm
from meta_sim.render.plan import population_space
from meta_sim.sim import tiles
from meta_sim.sim.design import DesignSpace, builtin_spaces
from meta_sim.sim.presets import DesignPreset, population, save_preset

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["--tile-px", "48", "--gsd", "2.4"]
QUIET = {"progress": False}


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _job(space):
    # Three designs in one city, two tiles each: a kill after the first tile lands inside the job.
    return ["--random-designs", "3", "--seed", "31", "--cities", "1", "--tiles", "2", "--space", space, *SMALL]


def _plan(path, space):
    result = _cli("jobs", "plan", *_job(space), "--out", path)
    assert result.exit_code == 0, result.output
    return farm.load(path)


@pytest.fixture(scope="module")
def dask_address():
    """One local Dask cluster for the module, reached by its address as a farm's scheduler is."""
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp",
                      dashboard_address=None) as cluster:
        yield cluster.scheduler_address


@pytest.mark.parametrize("space", builtin_spaces())
def test_manifest_of_every_shipped_space_loads_as_planned(space, tmp_path):
    manifest = _plan(tmp_path / "job.json", space)
    data = json.loads((tmp_path / "job.json").read_text())
    assert data["space"]["name"] == space and len(manifest.tasks) == 3
    assert all(set(t.design) == set(DesignSpace.load(space).names) for t in manifest.tasks)
    status = _cli("jobs", "status", tmp_path / "job.json")
    assert status.exit_code == 1 and "0/3 tasks complete" in status.output, status.output  # nothing rendered yet


def test_a_manifest_planned_before_the_fix_still_loads(tmp_path):
    """data/planned-before-the-fix.json: `jobs plan --space overhead-towns-v8` as the code before this test
    wrote it; every interface refused it then."""
    path = tmp_path / "job.json"
    shutil.copy(Path(__file__).parent / "data" / "planned-before-the-fix.json", path)
    manifest = farm.load(path)
    assert manifest.space["name"] == "overhead-towns-v8" and len(manifest.tasks) == 2
    status = _cli("jobs", "status", path)
    assert status.exit_code == 1 and "0/2 tasks complete" in status.output, status.output


def test_task_names_read_the_design_in_the_spaces_order_whatever_the_dicts(tmp_path):
    space = DesignSpace.load("overhead-towns-v5")
    design = space.sample(np.random.default_rng(3), 1)[0]
    shuffled = dict(reversed(list(design.items())))
    settings = {"space": space.name}
    assert farm.task_name(design, 1, settings, space.names) == farm.task_name(shuffled, 1, settings, space.names)
    # A manifest task whose design was edited is still caught (its hash no longer matches).
    manifest = _plan(tmp_path / "job.json", space.name)
    data = json.loads((tmp_path / "job.json").read_text())
    key = next(k for k, v in data["tasks"][0]["design"].items() if isinstance(v, float))
    data["tasks"][0]["design"][key] = data["tasks"][0]["design"][key] * 0.5
    (tmp_path / "edited.json").write_text(json.dumps(data))
    with pytest.raises(MetaSimError, match="does not match its design"):
        farm.load(tmp_path / "edited.json")
    assert manifest.tasks[0].name.startswith(f"{manifest.tasks[0].design[space.names[0]]}+")


@pytest.mark.parametrize("space", builtin_spaces())
def test_every_farm_interface_renders_every_shipped_space(space, tmp_path, dask_address):
    # The reference: the Dask executor, uninterrupted.
    reference = _plan(tmp_path / "ref" / "job.json", space)
    summary = executors.run(reference, executors.RunOptions(executor="dask", scheduler=dask_address, recycle=3,
                                                            **QUIET))
    assert not summary.failed and summary.rendered == reference.n_outputs == 6, summary.failed
    pixels = job_pixels(reference)
    meta = tiles.read_meta(reference.out_dir / reference.tasks[0].outputs[0])
    assert meta["design_space"] == space and meta["design"] == reference.tasks[0].design

    # The local executor, its process group killed once the first tile is written, then run again.
    path = tmp_path / "killed" / "job.json"
    manifest = _plan(path, space)
    run = subprocess.Popen([sys.executable, "-m", "meta_sim.cli", "jobs", "run", str(path), "--workers", "1"],
                           cwd=ROOT, start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while not list(manifest.out_dir.glob("[!.]*.exr")) and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.002)
    os.killpg(run.pid, signal.SIGKILL)
    run.wait()
    status = farm.check(manifest)
    assert status.count(farm.DONE) >= 1 and status.count(farm.MISSING) >= 1
    resumed = _cli("jobs", "run", path, "--workers", 1)
    assert resumed.exit_code == 0, resumed.output
    done = _cli("jobs", "status", path)
    assert done.exit_code == 0 and "3/3 tasks complete" in done.output, done.output
    assert_same_tiles(job_pixels(manifest), pixels)

    # One shard of two through the farm's Blender script (here with the bpy module's Python).
    sharded = _plan(tmp_path / "shard" / "job.json", space)
    shard = subprocess.run([sys.executable, "jobs/farm_shard.py", "--", "--manifest", str(tmp_path / "shard" /
                            "job.json"), "--shard", "1/2"], cwd=ROOT, capture_output=True, text=True)
    assert shard.returncode == 0, shard.stderr
    assert farm.check(sharded).complete_tasks == {t.name for t in sharded.tasks[1::2]}
    assert_same_tiles(job_pixels(sharded, sharded.tasks[1::2]), {k: v for k, v in pixels.items()
                                                  if k in {o for t in sharded.tasks[1::2] for o in t.outputs}})

    # The Flamenco job type of the manifest parses.
    flamenco = _cli("jobs", "export-flamenco", path, "--out", tmp_path / "flamenco", "--shards", 2)
    assert flamenco.exit_code == 0, flamenco.output
    if shutil.which("node") is None:
        pytest.skip("node is not installed: cannot parse the exported JavaScript")
    check = subprocess.run(["node", "--check", str(tmp_path / "flamenco" / "meta_sim_job.js")],
                           capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def _population(space: DesignSpace, n: int, seed: int) -> DesignPreset:
    """A population as `meta-sim infer` writes it: the group presets' designs and their distribution."""
    groups = [DesignPreset(kind="group", name=f"g{k}", design_space=space.name, design=design,
                           source_images=[f"g{k}.png"])
              for k, design in enumerate(space.sample(np.random.default_rng(seed), n))]
    return population(groups, space, "population")


@pytest.mark.parametrize("space", builtin_spaces())
def test_render_population_renders_in_the_populations_own_space(space, tmp_path):
    declared = DesignSpace.load(space)
    pop = _population(declared, 2, 5)
    save_preset(tmp_path / "population.json", pop)
    out = tmp_path / "tiles"
    result = _cli("render", "--population", tmp_path / "population.json", "--images", 2, "-r", 0.5, "--seed", 3,
                  "--cities", 1, "--tiles", 1, *SMALL, "--out", out)  # no --space: the population's own
    assert result.exit_code == 0, result.output
    jobs = json.loads((out / "designs.json").read_text())["jobs"]
    assert len(jobs) == 2 and {j["design_space"] for j in jobs} == {space}
    for job in jobs:
        meta = tiles.read_meta(out / job["tiles"][0])
        assert meta["design_space"] == space and declared.validate(meta["design"]) == meta["design"]
    # The farm plans the same designs from the same population.
    plan = _cli("jobs", "plan", "--population", tmp_path / "population.json", "--images", 2, "-r", 0.5, "--seed", 3,
                "--cities", 1, "--tiles", 1, *SMALL, "--out", tmp_path / "job.json")
    assert plan.exit_code == 0, plan.output
    assert [t.design for t in farm.load(tmp_path / "job.json").tasks] == [j["design"] for j in jobs]


def test_a_population_from_a_space_not_shipped_needs_its_file(tmp_path):
    space = DesignSpace.load("overhead-towns-v5")
    data = {**space.to_dict(), "name": "my-towns"}
    mine = DesignSpace.from_dict(data)
    (tmp_path / "my-towns.json").write_text(json.dumps(data))
    save_preset(tmp_path / "population.json", _population(mine, 2, 9))
    out = tmp_path / "tiles"
    args = ["render", "--population", tmp_path / "population.json", "--images", 1, "--tiles", 1, *SMALL]
    refused = _cli(*args, "--out", out)
    assert refused.exit_code == 2 and "which meta-sim does not ship; give that space's JSON with --space FILE" \
        in refused.output and len(refused.output.strip().splitlines()) == 1, refused.output
    assert not out.exists()
    wrong = _cli(*args, "--space", "overhead-towns-v5", "--out", out)
    assert wrong.exit_code == 2 and "inferred in design space 'my-towns', not 'overhead-towns-v5'" in wrong.output
    assert not out.exists()
    given = _cli(*args, "--space", tmp_path / "my-towns.json", "--out", out)
    assert given.exit_code == 0, given.output
    assert tiles.read_meta(next(out.glob("*.exr")))["design_space"] == "my-towns"
    unnamed = DesignPreset(kind="population", name="p", design_space="", design={})
    assert population_space(unnamed, "p.json").name == "rooftops-v1"  # populations that record none: as before
