"""Executors: run a job manifest's tasks in Blender worker processes, on this machine or on Dask.

The unit of work is a batch: up to ``recycle`` tasks rendered by one fresh
worker process (``python -m meta_sim.farm.worker --job FILE`` with the bpy module,
or a ``blender -b`` binary running ``jobs/farm_shard.py``), so Blender's
growth in memory over many renders is cut off every ``recycle`` tasks, a hung
or crashed process takes down one batch only, and a time-out can kill it.
The machine that ran a batch checks its tiles (readable, complete, metadata
of the task), so a remote Dask worker reports what it really wrote. A task
that did not complete is retried alone, up to ``retries`` times.

Both executors share that loop; they differ only in where a batch runs:
``local`` runs each batch from a thread of this process (the render itself is
the subprocess), ``dask`` submits it to a ``dask.distributed`` cluster (a
``LocalCluster``, or a remote scheduler whose workers see the same output
folder at the same path and have meta-sim installed).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent import futures as cf
from dataclasses import dataclass, field
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.extras import require
from ..core.progress import LineBar, on_terminal
from . import manifest as farm

EXECUTORS = ("local", "dask")
BLENDER_ENV = "META_SIM_BLENDER"
SHARD_SCRIPT = Path(__file__).resolve().parents[2] / "jobs" / "farm_shard.py"


@dataclass(frozen=True)
class Runner:
    """How a batch's worker process is started, on whichever machine runs the batch."""

    blender: str | None = None  # a Blender binary; None: this Python with the bpy module
    timeout: float | None = None  # seconds per task

    def command(self, job_file: Path) -> list[str]:
        """The command line that renders the batch manifest ``job_file``."""
        if self.blender:
            return [self.blender, "-b", "--python-exit-code", "1", "--python", str(SHARD_SCRIPT),
                    "--", "--manifest", str(job_file)]
        return [sys.executable, "-m", "meta_sim.farm.worker", "--job", str(job_file)]


@dataclass(frozen=True)
class RunOptions:
    """How ``run`` renders: the executor ("local" or "dask"), parallel worker processes, a Dask
    scheduler address, the Blender binary, a time-out per task, retries of a failed task, tasks per
    worker process before it is replaced, and whether to show a progress bar. ``run`` raises
    MetaSimError for a value out of range or a combination that cannot work."""

    executor: str = "local"
    workers: int = 2
    scheduler: str | None = None  # Dask scheduler address; None: a LocalCluster
    blender: str | None = None  # default: $META_SIM_BLENDER, else the bpy module
    timeout: float | None = None
    retries: int = 2
    recycle: int = 4  # tasks per worker process
    progress: bool = True


@dataclass
class RunSummary:
    """What ``run`` did: tasks and tiles in the manifest, tiles valid before and rendered during the
    run, the tasks that failed (with why) and their tiles, retries, wall seconds and one record per
    worker process."""

    tasks: int = 0
    tiles: int = 0
    already_done: int = 0  # tiles valid before the run
    rendered: int = 0  # tiles this run completed
    failed: dict = field(default_factory=dict)  # task name -> reason
    failed_tiles: int = 0
    retried: int = 0
    seconds: float = 0.0
    batches: list = field(default_factory=list)  # per worker process: seconds, peak RSS, tasks, host

    @property
    def tiles_done(self) -> int:
        """Valid tiles after the run."""
        return self.already_done + self.rendered

    @property
    def tiles_per_second(self) -> float:
        """Tiles this run rendered per wall second (0 before any time has passed)."""
        return self.rendered / self.seconds if self.seconds > 0 else 0.0


def run_batch(data: dict, runner: Runner) -> dict:
    """Render a batch (a manifest dict with an absolute ``out_dir``) in one worker process,
    then check its tiles here. Never raises for a failed render: the result says what failed."""
    manifest = farm.Manifest.from_dict(data, Path("/"))
    names = [t.name for t in manifest.tasks]
    with tempfile.TemporaryDirectory(prefix="meta-sim-batch-") as tmp:
        job_file, log_file = Path(tmp) / "job.json", Path(tmp) / "worker.log"
        job_file.write_text(json.dumps(data))
        started = time.perf_counter()
        returncode, timed_out, max_rss_kb = _run_process(runner.command(job_file), log_file,
                                                          runner.timeout and runner.timeout * len(names))
        seconds = time.perf_counter() - started
        log = log_file.read_text(errors="replace").splitlines()
    complete = farm.check(manifest).complete_tasks
    failed = {}
    for name in names:
        if name in complete:
            continue
        said = [line.split(": ", 2)[-1] for line in log if line.startswith(f"meta-sim worker: task {name} failed")]
        if said:
            failed[name] = said[-1]
        elif timed_out:
            failed[name] = f"timed out after {runner.timeout:g} s per task"
        else:
            tail = " | ".join(log[-3:]) or "no output"
            failed[name] = f"worker exited with code {returncode} before finishing the task ({tail})"
    return {"ok": [n for n in names if n in complete], "failed": failed, "returncode": returncode,
            "seconds": seconds, "max_rss_mb": max_rss_kb / 1024, "host": socket.gethostname(),
            "tasks": len(names)}


def _run_process(command: list[str], log_file: Path, timeout: float | None) -> tuple[int, bool, int]:
    """(exit code, timed out, peak RSS in KiB) of one worker process.

    ``os.wait4`` gives the peak memory of exactly this child (getrusage(RUSAGE_CHILDREN)
    would mix all the children of this process). The child stays in our process group,
    so Ctrl-C or a kill of the group stops it with us.
    """
    try:
        with open(log_file, "wb") as log:
            proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
    except OSError as exc:
        log_file.write_text(f"cannot start {command[0]}: {exc.strerror}\n")
        return 127, False, 0
    expired = threading.Event()

    def kill():
        expired.set()
        proc.kill()

    timer = threading.Timer(timeout, kill) if timeout else None
    if timer:
        timer.start()
    try:
        _, status, usage = os.wait4(proc.pid, 0)
    finally:
        if timer:
            timer.cancel()
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here, so Popen must not wait again
    return proc.returncode, expired.is_set(), usage.ru_maxrss


class _LocalPool:
    """Batches run from threads of this process; each thread waits on its worker process."""

    def __init__(self, workers: int):
        self.pool = cf.ThreadPoolExecutor(workers, thread_name_prefix="meta-sim-batch")

    def submit(self, fn, *args):
        return self.pool.submit(fn, *args)

    def wait_any(self, pending) -> set:
        return cf.wait(pending, return_when=cf.FIRST_COMPLETED).done

    def close(self):
        self.pool.shutdown(cancel_futures=True)


class _DaskPool:
    """Batches run on a dask.distributed cluster: a remote scheduler, or a LocalCluster of
    threads (the render is a subprocess anyway, so worker processes would add nothing)."""

    def __init__(self, workers: int, scheduler: str | None):
        from distributed import Client, LocalCluster
        self.cluster = None
        try:
            if scheduler:
                self.client = Client(scheduler, timeout="10s")
            else:
                self.cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=False,
                                            dashboard_address=None)
                self.client = Client(self.cluster)
        except OSError as exc:
            raise MetaSimError(f"cannot reach the Dask scheduler {scheduler}: {exc}; "
                               "check the address (tcp://HOST:8786) and that the scheduler runs") from None

    def submit(self, fn, *args):
        return self.client.submit(fn, *args, pure=False)  # a retry must run again, not hit a cached result

    def wait_any(self, pending) -> set:
        from distributed import wait

        return wait(list(pending), return_when="FIRST_COMPLETED").done

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def _check(options: RunOptions) -> Runner:
    if options.executor not in EXECUTORS:
        raise MetaSimError(f"unknown executor {options.executor!r}; choose one of {', '.join(EXECUTORS)}")
    for name, value, low in (("workers", options.workers, 1), ("retries", options.retries, 0),
                             ("recycle", options.recycle, 1)):
        if value < low:
            raise MetaSimError(f"--{name} must be at least {low}")
    if options.timeout is not None and options.timeout <= 0:
        raise MetaSimError("--timeout must be a positive number of seconds")
    if options.scheduler and options.executor != "dask":
        raise MetaSimError("--scheduler is for --executor dask")
    blender = options.blender or os.environ.get(BLENDER_ENV) or None
    if blender and options.executor == "local" and shutil.which(blender) is None:
        raise MetaSimError(f"no Blender executable at {blender!r}; give --blender PATH "
                           f"(or unset {BLENDER_ENV} to use the bpy module)")
    if options.executor == "dask":
        require("distributed", "the dask executor")
    elif not blender:
        require("bpy", "rendering in local worker processes without --blender")
    return Runner(blender=blender, timeout=options.timeout)


def run(manifest: farm.Manifest, options: RunOptions = RunOptions()) -> RunSummary:
    """Render every task whose tiles are not all valid; retry failures; summarise.

    Leftover temporary tiles are removed first, and the texture banks are built here once, before the
    workers start. Failed renders do not raise: they are in the summary's ``failed``. Raises
    MetaSimError for bad ``options`` (see ``RunOptions``), a missing Blender, bpy or distributed, or an
    unreachable Dask scheduler.
    """
    from tqdm import tqdm

    runner = _check(options)
    farm.render_setup(manifest)  # builds the banks once here, before workers race to
    _remove_abandoned(manifest)
    started = time.perf_counter()
    status = farm.check(manifest)
    summary = RunSummary(tasks=len(manifest.tasks), tiles=manifest.n_outputs, already_done=status.count(farm.DONE))
    pending = [t for t in manifest.tasks if t.name not in status.complete_tasks]
    by_name = {t.name: t for t in pending}
    new_tiles = {t.name: sum(1 for _, state in status.states[t.name] if state != farm.DONE) for t in pending}
    pool = _DaskPool(options.workers, options.scheduler) if options.executor == "dask" else _LocalPool(options.workers)
    attempts = Counter()
    if not options.progress:
        bar = tqdm(total=summary.tiles, disable=True)
    elif on_terminal():
        bar = tqdm(total=summary.tiles, initial=summary.already_done, unit="tile", desc="render")
    else:
        bar = LineBar(summary.tiles, "render", "tile", initial=summary.already_done)

    def submit(tasks):
        data = manifest.subset(tasks).to_dict()  # out_dir absolute: the worker may run anywhere
        running[pool.submit(run_batch, data, runner)] = [t.name for t in tasks]

    running = {}
    try:
        for k in range(0, len(pending), options.recycle):
            submit(pending[k:k + options.recycle])
        while running:
            for future in pool.wait_any(running):
                names = running.pop(future)
                try:
                    result = future.result()
                except Exception as exc:  # the executor lost the batch (a Dask worker died, ...)
                    result = {"ok": [], "failed": {n: f"executor error: {exc}" for n in names}}
                else:
                    summary.batches.append({k: result[k] for k in ("seconds", "max_rss_mb", "host", "tasks",
                                                                   "returncode")})
                for name in result["ok"]:
                    summary.rendered += new_tiles[name]
                    bar.update(new_tiles[name])
                for name, reason in result["failed"].items():
                    attempts[name] += 1
                    if attempts[name] <= options.retries:
                        summary.retried += 1
                        submit([by_name[name]])
                    else:
                        summary.failed[name] = f"{reason} (after {attempts[name]} attempts)"
                        summary.failed_tiles += len(by_name[name].tiles)
    finally:
        bar.close()
        pool.close()
    _remove_abandoned(manifest)  # again: a worker killed just before this run started is gone by now
    summary.seconds = time.perf_counter() - started
    return summary


def _remove_abandoned(manifest: farm.Manifest) -> None:
    """Temporary tiles of workers that are gone; those of live workers (another run) are left alone."""
    for path in farm.temporaries(manifest, abandoned_only=True):
        path.unlink(missing_ok=True)
