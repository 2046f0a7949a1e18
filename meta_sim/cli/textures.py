"""`meta-sim textures`: build, list, compare and draw texture banks."""

from __future__ import annotations

from pathlib import Path

import click

from ..core.errors import MetaSimError
from ..sim.textures.procedural import FIRST_HELDOUT, HELDOUT_SETS
from .base import main


@main.group()
def textures():
    """Build, inspect and compare texture banks."""


@textures.command("build")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="folder for the bank (default: the cache folder the renderer uses)")
@click.option("--from", "source", type=click.Path(path_type=Path), default=None,
              help="build from your own photos: a folder with flat/ and sloped/ subfolders")
@click.option("--heldout", type=click.Choice(list(HELDOUT_SETS)), is_flag=False, flag_value=FIRST_HELDOUT,
              default=None,
              help="build a held-out set (design-gap textures) instead: heldout-v1 (the set `--heldout` "
                   "alone builds; a single seed's E2), heldout-v2 (E2 test), heldout-v3 (a check on textures "
                   "no choice looked at), heldout-v4 (E2 validation for a day) or heldout-v5 (E2 validation: "
                   "heldout-v4 and 20 + 20 drawn textures)")
@click.option("--size", type=int, default=256, show_default=True, help="texture size in pixels")
@click.option("--repeat-m", type=float, default=8.0, show_default=True,
              help="with --from: physical size of one photo repeat in metres")
def textures_build(out, source, heldout, size, repeat_m):
    """Write a texture bank: images, manifest.json and the HSV similarity matrix."""
    from ..core.fileio import made_folder
    from ..sim import textures as tx
    from ..sim.textures.bank import build_into, check_size

    check_size(size)
    if source is not None:
        if out is None:
            raise MetaSimError("with --from, give the bank folder to write with --out")
        with made_folder(out.parent):
            bank = build_into(out, lambda d: tx.build_bank_from_folder(source, d, repeat_m=repeat_m, size=size))
    elif out is None:
        bank = tx.ensure_heldout_bank(name=heldout) if heldout else tx.ensure_default_bank()
    else:
        with made_folder(out.parent):
            bank = build_into(out, lambda d: tx.build_default_bank(d, size=size, heldout=heldout or False))
    counts = {kind: len(bank.ids(kind)) for kind in ("flat", "sloped")}
    click.echo(f"bank {bank.root}: {counts['flat']} flat, {counts['sloped']} sloped textures")


def _bank(path):
    from ..sim import textures as tx

    return tx.load_bank(path) if path else tx.ensure_default_bank()


@textures.command("list")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
def textures_list(bank):
    """Print index, id, kind, repeat size and name of every texture."""
    bank = _bank(bank)
    for kind in ("flat", "sloped"):
        for index, texture_id in enumerate(bank.ids(kind)):
            entry = bank.by_id(texture_id)
            click.echo(f"{kind:6s} {index:3d}  {entry.id:32s} {entry.repeat_m:5.1f} m  {entry.name}")


@textures.command("sheet")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="PNG file to write")
@click.option("--thumb", type=int, default=96, show_default=True, help="thumbnail size in pixels")
def textures_sheet(bank, out, thumb):
    """Write a contact sheet PNG of a bank (flat textures first, then sloped)."""
    from ..core.fileio import writable_dir
    from ..sim import textures as tx

    if not 8 <= thumb <= 1024:
        raise MetaSimError(f"--thumb must be from 8 to 1024 pixels, not {thumb}")
    writable_dir(Path(out).parent)
    tx.contact_sheet(_bank(bank), out, thumb=thumb)
    click.echo(f"wrote {out}")


@textures.command("similarity")
@click.option("--bank", type=click.Path(path_type=Path), default=None, help="bank folder (default: built-in)")
@click.option("--against", type=click.Path(path_type=Path), default=None,
              help="score this bank's textures (rows) against --bank (columns), e.g. the held-out set")
@click.option("--out", type=click.Path(path_type=Path), required=True, help="JSON file to write")
def textures_similarity(bank, against, out):
    """Write the HSV colour similarity matrix (histogram intersection on the HSV cone)."""
    from ..sim import textures as tx

    base = _bank(bank)
    if against is None:
        tx.write_similarity(base, out)
    else:
        tx.write_similarity(tx.load_bank(against), out, other_bank=base)
    click.echo(f"wrote {out}")
