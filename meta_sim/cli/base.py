"""The `meta-sim` command group and what its commands share: one-line errors, progress bars, threads."""

from __future__ import annotations

import functools
import os
import sys

import click

from ..core.errors import MetaSimError
from ..core.progress import LineBar, on_terminal

# nams.model.ARCHITECTURES, named here so that `--help` does not import torch (a test keeps them equal).
ARCHITECTURE_NAMES = ("paper", "factorised", "additive")


class _Group(click.Group):
    """Prints MetaSimError as one line and exits 2, without a traceback."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except MetaSimError as exc:
            click.echo(f"error: {exc}", err=True)
            sys.exit(2)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="meta-sim")
def main():
    """meta-sim: design synthetic overhead imagery by Neural-Adjoint Meta-Simulation."""


def _torch_threads(command):
    """Run a torch-side command with META_SIM_THREADS intra-op threads, else all CPUs but one.

    Torch's default, one thread per CPU, slows down badly as soon as anything else runs (Blender
    rendering beside training, say): its threads wait for one another at every operation, so one
    that shares a CPU holds up the rest. So one CPU is left free. Raises MetaSimError when
    META_SIM_THREADS is not a whole number.
    """

    @functools.wraps(command)
    def run(*args, **kwargs):
        import torch

        wanted = os.environ.get("META_SIM_THREADS")
        try:
            threads = int(wanted) if wanted else max(1, (os.cpu_count() or 1) - 1)
        except ValueError:
            raise MetaSimError(f"META_SIM_THREADS must be a whole number, not {wanted!r}") from None
        torch.set_num_threads(max(1, threads))
        return command(*args, **kwargs)

    return run


class _Bars:
    """One tqdm bar per stage; opening the next closes the previous one. A bar appears with the
    stage's first step, so a stage that finds everything cached shows none."""

    def __init__(self):
        self.bar = None
        self.stage = 0

    def __call__(self, label: str, total: int):
        from tqdm import tqdm

        self.close()
        self.stage += 1
        stage = self.stage

        def update(n: int = 1) -> None:
            if stage != self.stage:  # a stage already closed
                return
            if self.bar is None:
                self.bar = (tqdm(total=total, desc=label, unit="it", leave=True) if on_terminal()
                            else LineBar(total, label))
            self.bar.update(n)

        return update

    def close(self):
        if self.bar is not None:
            self.bar.close()
            self.bar = None
