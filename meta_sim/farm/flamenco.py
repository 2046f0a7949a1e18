"""Export a job manifest as a Flamenco v3 custom job type (JavaScript).

Flamenco reads job types from ``*.js`` files in its manager's ``scripts/``
folder: ``const JOB_TYPE = {label, settings}`` describes the submission form
and ``compileJob(job)`` turns one submission into tasks. The exported type
makes one task per shard, each a ``blender-render`` command that opens no
blend file and runs ``jobs/farm_shard.py`` (``blender -b --python-exit-code 1
--python jobs/farm_shard.py -- --manifest M --shard i/n``); Flamenco's
``{blender}`` and ``{blenderArgs}`` variables name the Blender of each
worker. Workers need the manifest, this repository and the output folder on
shared storage; the defaults are this machine's paths and can be edited in
the form. A shard resumes (valid tiles are skipped), so requeueing a failed
Flamenco task is safe.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.fileio import write_text_atomic
from .manifest import Manifest

REPOSITORY = Path(__file__).resolve().parents[2]
TASKS_PER_SHARD = 8  # default shard size: one Blender start-up amortised over several designs

TEMPLATE = """// meta-sim render job for Flamenco v3, exported by `meta-sim jobs export-flamenco`.
// Manifest: %(manifest_js)s (%(tasks)d tasks, %(tiles)d tiles). Put this file in the
// Flamenco manager's scripts/ folder and restart the manager; submit with its API or web UI.

const JOB_TYPE = {
    label: %(label)s,
    description: "Renders the tasks of a meta-sim job manifest in shards, one Blender process per shard",
    settings: [
        { key: "manifest", type: "string", subtype: "file_path", required: true, default: %(manifest_js)s,
          description: "Job manifest (meta-sim jobs plan), on storage every worker sees" },
        { key: "repository", type: "string", subtype: "dir_path", required: true, default: %(repository_js)s,
          description: "meta-sim repository holding jobs/farm_shard.py, on storage every worker sees" },
        { key: "shards", type: "int32", required: true, default: %(shards)d, propargs: {min: 1, max: %(tasks)d},
          description: "Flamenco tasks to split the job into (each renders every n-th manifest task)" },
    ]
};

function compileJob(job) {
    const settings = job.settings;
    const shards = settings.shards;
    if (!(shards >= 1 && shards <= %(tasks)d)) {
        throw `shards must be between 1 and %(tasks)d, not ${shards}`;
    }
    const script = path.join(settings.repository, "jobs", "farm_shard.py");
    for (let i = 0; i < shards; i++) {
        const task = author.Task(`shard-${i}-of-${shards}`, "blender");
        task.addCommand(author.Command("blender-render", {
            exe: "{blender}",
            exeArgs: "{blenderArgs}",
            argsBefore: [],
            blendfile: "",
            args: ["--python-exit-code", "1", "--python", script, "--",
                   "--manifest", settings.manifest, "--shard", `${i}/${shards}`],
        }));
        job.addTask(task);
    }
}
"""


def _js(text: str) -> str:
    """``text`` as a JavaScript string literal that nothing can break out of: JSON with every non-ASCII
    character (U+2028 and U+2029 end a line in a comment) and ``<``, ``>``, ``&`` escaped."""
    literal = json.dumps(str(text), ensure_ascii=True)
    return literal.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def job_type_name(manifest_path: Path) -> str:
    """Flamenco names a job type after its file; keep it to safe characters."""
    return "meta_sim_" + re.sub(r"[^A-Za-z0-9_]", "_", Path(manifest_path).stem)


def export(manifest: Manifest, manifest_path: Path, out_dir: Path, shards: int | None = None) -> Path:
    """Write the Flamenco job type for ``manifest`` (saved at ``manifest_path``) into ``out_dir`` as
    ``meta_sim_<manifest stem>.js`` and return its path.

    ``shards`` is the form's default number of Flamenco tasks (default: one per ``TASKS_PER_SHARD``
    manifest tasks). Raises MetaSimError when the manifest has no tasks, ``shards`` is not between 1
    and the number of tasks, or ``out_dir`` cannot be written.
    """
    if not manifest.tasks:
        raise MetaSimError("the manifest has no tasks; plan a job with designs first")
    count = len(manifest.tasks)
    shards = shards if shards is not None else max(1, -(-count // TASKS_PER_SHARD))
    if not 1 <= shards <= count:
        raise MetaSimError(f"--shards must be between 1 and the number of tasks ({count})")
    manifest_path = Path(manifest_path).resolve()
    name = job_type_name(manifest_path)
    text = TEMPLATE % {
        "label": _js(f"meta-sim {manifest_path.stem} ({count} tasks)"), "manifest_js": _js(str(manifest_path)),
        "repository_js": _js(str(REPOSITORY)), "shards": int(shards), "tasks": count, "tiles": manifest.n_outputs}
    try:
        return write_text_atomic(Path(out_dir) / f"{name}.js", text)
    except OSError as exc:
        raise MetaSimError(f"cannot write the job type into {out_dir}: {exc.strerror}; choose another --out") from None
