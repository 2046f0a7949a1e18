"""The render farm: manifests, local and Dask executors, shards, Flamenco export, and faults.

Small tiles (48 px at 2.4 m/px) and few tasks keep real Blender renders fast.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from click.testing import CliRunner
from toys import assert_same_tiles, job_pixels

from meta_sim.cli import main as cli
from meta_sim.core import fileio
from meta_sim.core.errors import MetaSimError
from meta_sim.farm import executors
from meta_sim.farm import manifest as farm
from meta_sim.sim import tiles

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["--tile-px", "48", "--gsd", "2.4"]
# 12 tiles per task: a 4 x 3 grid rendered as two blocks, so a task is written in two steps.
JOB = ["--random-designs", "4", "--seed", "21", "--cities", "2", "--tiles", "12", *SMALL]
QUIET = {"progress": False}


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def _plan(path, *args, out_dir=None):
    extra = ["--out-dir", out_dir] if out_dir else []
    result = _cli("jobs", "plan", *(args or JOB), "--out", path, *extra)
    assert result.exit_code == 0, result.output
    return farm.load(path)


def _counts(manifest):
    status = farm.check(manifest)
    return status.count(farm.DONE), status.count(farm.MISSING), status.count(farm.CORRUPT)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The job rendered once, uninterrupted, by the local executor."""
    folder = tmp_path_factory.mktemp("farm-reference")
    manifest = _plan(folder / "job.json")
    summary = executors.run(manifest, executors.RunOptions(workers=2, recycle=2, **QUIET))
    assert not summary.failed and summary.rendered == manifest.n_outputs == 48
    return manifest, job_pixels(manifest)


def test_plan_is_a_pure_function_of_content(tmp_path, reference):
    first = _plan(tmp_path / "a.json")
    text = (tmp_path / "a.json").read_text()
    _plan(tmp_path / "a.json")
    assert (tmp_path / "a.json").read_text() == text  # byte for byte
    data = json.loads(text)
    assert data["format"] == "meta-sim-farm-job" and data["version"] == 1
    assert data["out_dir"] == "a-tiles" and first.out_dir == (tmp_path / "a-tiles").resolve()
    # Task names depend on what is rendered, not on where: the reference job has the same tasks.
    assert [t.name for t in first.tasks] == [t.name for t in reference[0].tasks]
    assert [t.city_seed for t in first.tasks] == [21, 22, 21, 22]
    task = first.tasks[0]
    assert task.tiles == tuple(range(12)) and task.outputs[3] == f"{task.name}_t03.exr"
    one = _plan(tmp_path / "one.json", "--design", "flat_roof=6,sloped_roof=11", "--seed", "21", "--tiles", "6",
                "--preset", "fast", *SMALL)
    assert len(one.tasks) == 1 and one.tasks[0].design == {"flat_roof": "flat-membrane-white-tpo",
                                                           "sloped_roof": one.tasks[0].design["sloped_roof"]}
    assert one.tasks[0].name.startswith("flat-membrane-white-tpo+")
    other = _plan(tmp_path / "two.json", "--design", "flat_roof=6,sloped_roof=11", "--seed", "21", "--tiles", "6",
                  "--preset", "balanced", *SMALL)
    assert other.tasks[0].name != one.tasks[0].name  # a different preset renders different pixels
    bad = _cli("jobs", "plan", "--tiles", 2, "--out", tmp_path / "bad.json")
    assert bad.exit_code == 2 and "exactly one of --design, --random-designs or --population" in bad.output
    missing = _cli("jobs", "status", tmp_path / "nope.json")
    assert missing.exit_code == 2 and "meta-sim jobs plan" in missing.output


def test_worker_killed_mid_task_then_resumed_gives_identical_tiles(tmp_path, reference):
    manifest = _plan(tmp_path / "job.json")
    out = manifest.out_dir
    run = subprocess.Popen([sys.executable, "-m", "meta_sim.cli", "jobs", "run", str(tmp_path / "job.json"),
                            "--workers", "2", "--recycle", "2"], cwd=ROOT, start_new_session=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not list(out.glob("[!.]*.exr")) and time.monotonic() < deadline and run.poll() is None:
        time.sleep(0.002)
    os.killpg(run.pid, signal.SIGKILL)  # the executor and every Blender worker at once
    run.wait()
    status = farm.check(manifest)
    partial = [name for name, states in status.states.items()
               if {s for _, s in states} >= {farm.DONE, farm.MISSING}]
    assert status.count(farm.DONE) >= 1 and status.count(farm.MISSING) >= 1
    assert partial, "the kill should land inside a task"
    result = _cli("jobs", "run", tmp_path / "job.json", "--workers", 2)
    assert result.exit_code == 0, result.output
    assert _counts(manifest) == (48, 0, 0) and not farm.temporaries(manifest)
    assert_same_tiles(job_pixels(manifest), reference[1])


def test_truncated_or_foreign_tile_is_reported_corrupt_and_rerendered(tmp_path, reference):
    manifest = _plan(tmp_path / "job.json")
    shutil.copytree(reference[0].out_dir, manifest.out_dir)
    first, second = manifest.tasks[0], manifest.tasks[1]
    truncated = manifest.out_dir / first.outputs[5]
    truncated.write_bytes(truncated.read_bytes()[: truncated.stat().st_size // 2])
    shutil.copy(manifest.out_dir / first.outputs[0], manifest.out_dir / second.outputs[0])  # wrong metadata
    (manifest.out_dir / second.outputs[1]).unlink()
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = f".{second.outputs[2][:-4]}.tmp{int(gone.stdout)}-{fileio._host()}-x1.exr"  # a killed worker's
    (manifest.out_dir / dead).write_bytes(b"half a tile")
    status = _cli("jobs", "status", tmp_path / "job.json", "--list")
    assert status.exit_code == 1, status.output  # tiles missing or corrupt
    assert "2/4 tasks complete; tiles: 45 done, 1 missing, 2 corrupt (of 48)" in status.output
    assert f"corrupt  {truncated}" in status.output and "1 half-written temporary files" in status.output
    summary = executors.run(manifest, executors.RunOptions(workers=2, **QUIET))
    assert summary.rendered == 3 and summary.already_done == 45 and not summary.failed
    assert _counts(manifest) == (48, 0, 0) and not farm.temporaries(manifest)
    assert _cli("jobs", "status", tmp_path / "job.json").exit_code == 0
    assert_same_tiles(job_pixels(manifest), reference[1])


def test_task_that_always_fails_is_retried_then_reported_while_others_complete(tmp_path, bank):
    from dataclasses import replace

    from meta_sim.sim.textures import load_bank
    from meta_sim.sim.textures.bank import save_manifest

    copy = tmp_path / "bank"
    shutil.copytree(bank.root, copy)
    manifest = _plan(tmp_path / "job.json", "--bank", copy, "--random-designs", "3", "--seed", "5", "--tiles", "2",
                     *SMALL)
    flats = [t.design["flat_roof"] for t in manifest.tasks]
    doomed = next(t for t in manifest.tasks if flats.count(t.design["flat_roof"]) == 1)
    # The bank loses one texture after planning: that task cannot render, whatever the retries.
    edited = load_bank(copy)
    gone = edited.by_id(doomed.design["flat_roof"])
    save_manifest(replace(edited, entries=tuple(e for e in edited.entries if e.id != gone.id)))
    (copy / gone.path).unlink()
    result = _cli("jobs", "run", tmp_path / "job.json", "--workers", 2, "--retries", 2, "--recycle", 3)
    assert result.exit_code == 1, result.output
    assert f"failed: {doomed.name}: flat_roof: texture {gone.id!r} is in none of the texture banks" in result.output
    assert "(after 3 attempts)" in result.output
    n = len(manifest.tasks)
    assert f"{2 * (n - 1)}/{2 * n} tiles done" in result.output and ", 2 failed" in result.output
    status = farm.check(manifest)
    assert status.complete_tasks == {t.name for t in manifest.tasks} - {doomed.name}


def test_time_out_kills_the_worker_and_fails_the_task(tmp_path, reference):
    manifest = _plan(tmp_path / "job.json", "--design", "flat_roof=1,sloped_roof=1", "--tiles", "1", *SMALL)
    summary = executors.run(manifest, executors.RunOptions(timeout=0.05, retries=1, **QUIET))
    assert list(summary.failed) == [manifest.tasks[0].name]
    assert "timed out after 0.05 s per task (after 2 attempts)" in summary.failed[manifest.tasks[0].name]


def test_dask_local_cluster_and_scheduler_address_render_the_same_tiles(tmp_path, reference):
    from distributed import LocalCluster

    manifest = _plan(tmp_path / "job.json")
    summary = executors.run(manifest, executors.RunOptions(executor="dask", workers=2, **QUIET))
    assert not summary.failed and summary.rendered == 48
    assert {b["tasks"] for b in summary.batches} == {4}  # default recycle: 4 tasks per worker process
    assert_same_tiles(job_pixels(manifest), reference[1])
    # The code path of a remote cluster: a scheduler reached by its address.
    remote = _plan(tmp_path / "remote.json")
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp",
                      dashboard_address=None) as cluster:
        summary = executors.run(remote, executors.RunOptions(executor="dask", scheduler=cluster.scheduler_address,
                                                             recycle=2, **QUIET))
    assert not summary.failed and summary.rendered == 48
    assert_same_tiles(job_pixels(remote), reference[1])


def test_shards_and_a_blender_binary_render_the_same_tiles(tmp_path, reference):
    manifest = _plan(tmp_path / "job.json")
    shard = subprocess.run([sys.executable, "jobs/farm_shard.py", "--", "--manifest", str(tmp_path / "job.json"),
                            "--shard", "0/2"], cwd=ROOT, capture_output=True, text=True)
    assert shard.returncode == 0, shard.stderr
    assert farm.check(manifest).complete_tasks == {t.name for t in manifest.tasks[0::2]}
    # A stand-in for `blender`: runs the --python script with this Python and the bpy module.
    blender = tmp_path / "blender"
    # Called as: blender -b --python-exit-code 1 --python SCRIPT -- ARGS
    blender.write_text(f'#!/bin/sh\nexec "{sys.executable}" "$5" "$@"\n')
    blender.chmod(0o755)
    result = _cli("jobs", "run", tmp_path / "job.json", "--blender", blender)
    assert result.exit_code == 0, result.output
    assert "24 rendered now, 24 already valid" in result.output
    assert_same_tiles(job_pixels(manifest), reference[1])
    bad = _cli("jobs", "run", tmp_path / "job.json", "--blender", tmp_path / "no-blender")
    assert bad.exit_code == 2 and "no Blender executable" in bad.output
    wrong = subprocess.run([sys.executable, "jobs/farm_shard.py", "--", "--manifest", str(tmp_path / "job.json"),
                            "--shard", "2/2"], cwd=ROOT, capture_output=True, text=True)
    assert wrong.returncode == 2 and "0 <= i < n" in wrong.stderr


NODE_HARNESS = """
const fs = require("fs"), vm = require("vm"), nodePath = require("path");
const tasks = [];
const sandbox = {
  print: () => {}, path: {join: (...p) => nodePath.posix.join(...p)},
  author: {
    Task: (name, type) => ({name, type, commands: [], addCommand(c) { this.commands.push(c); }}),
    Command: (name, params) => ({name, params}),
  },
};
vm.createContext(sandbox);
vm.runInContext(fs.readFileSync(process.argv[2], "utf8") + "\\nthis.JOB_TYPE = JOB_TYPE;", sandbox);
const settings = {};
for (const s of sandbox.JOB_TYPE.settings) settings[s.key] = s.default;
sandbox.compileJob({settings, addTask: (t) => tasks.push(t)});
console.log(JSON.stringify({label: sandbox.JOB_TYPE.label, tasks, pwned: sandbox.pwned !== undefined}));
"""


def _export_and_compile(tmp_path, manifest_path, shards):
    """Export the manifest's Flamenco job type, check Node parses it, and compile it in a stub Flamenco."""
    if shutil.which("node") is None:
        pytest.skip("node is not installed: cannot parse the exported JavaScript")
    _plan(manifest_path)
    result = _cli("jobs", "export-flamenco", manifest_path, "--out", tmp_path / "flamenco", "--shards", shards)
    assert result.exit_code == 0, result.output
    script = tmp_path / "flamenco" / "meta_sim_job.js"
    check = subprocess.run(["node", "--check", str(script)], capture_output=True, text=True)
    assert check.returncode == 0, check.stderr
    harness = tmp_path / "harness.js"
    harness.write_text(NODE_HARNESS)
    run = subprocess.run(["node", str(harness), str(script)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    return script, json.loads(run.stdout)


def test_flamenco_job_type_parses_and_compiles_one_task_per_shard(tmp_path, reference):
    manifest_path = tmp_path / "job.json"
    _, compiled = _export_and_compile(tmp_path, manifest_path, 3)
    assert [t["name"] for t in compiled["tasks"]] == ["shard-0-of-3", "shard-1-of-3", "shard-2-of-3"]
    command = compiled["tasks"][1]["commands"][0]
    assert command["name"] == "blender-render" and command["params"]["exe"] == "{blender}"
    assert command["params"]["args"] == ["--python-exit-code", "1", "--python", str(ROOT / "jobs" / "farm_shard.py"),
                                         "--", "--manifest", str(manifest_path.resolve()), "--shard", "1/3"]
    too_many = _cli("jobs", "export-flamenco", manifest_path, "--out", tmp_path / "f2", "--shards", 9)
    assert too_many.exit_code == 2 and "--shards must be between 1 and" in too_many.output


def test_flamenco_export_of_a_hostile_path_runs_no_code(tmp_path, reference):
    """Quotes, newlines, U+2028 and script-like text in the manifest's path stay inside string literals."""
    folder = tmp_path / 'evil"\n;globalThis.pwned = 1; <script>--><!--\u2028globalThis.pwned = 2;\'`${x}'
    folder.mkdir()
    manifest_path = folder / "job.json"
    script, compiled = _export_and_compile(tmp_path, manifest_path, 2)
    assert "<script>" not in script.read_text() and "\u2028" not in script.read_text()
    assert compiled["pwned"] is False
    assert compiled["tasks"][0]["commands"][0]["params"]["args"][6] == str(manifest_path.resolve())


def test_a_job_carries_its_sensor_ground_roof_jitter_and_style_to_the_workers(tmp_path, reference):
    args = ["--design", "flat_roof=6,sloped_roof=11", "--seed", "21", "--tiles", "2", *SMALL]
    plain = _plan(tmp_path / "plain.json", *args)
    dressed = _plan(tmp_path / "dressed.json", *args, "--sensor", "drone", "--ground", "mixed", "--roof-jitter", "0.5",
                    "--style", "dense=3,suburban=1")
    assert plain.appearance == farm.DEFAULT_APPEARANCE
    assert dressed.appearance == {"sensor": "drone", "roof_jitter": 0.5, "ground": "mixed",
                                  "style": "suburban=0.25,dense=0.75"}
    assert dressed.tasks[0].name != plain.tasks[0].name  # other pixels, another task
    summary = executors.run(dressed, executors.RunOptions(workers=1, **QUIET))
    assert not summary.failed and _counts(dressed) == (2, 0, 0)
    meta = tiles.read_meta(dressed.out_dir / dressed.tasks[0].outputs[0])
    assert meta["sensor"]["name"] == "drone" and meta["ground"] == "mixed" and meta["roof_jitter"] == 0.5
    assert meta["style"] == "suburban=0.25,dense=0.75"
    data = json.loads((tmp_path / "dressed.json").read_text())
    data["appearance"]["sensor"] = "xray"
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(MetaSimError, match="unknown sensor"):
        farm.load(tmp_path / "bad.json")
