"""Where E2's top-10 misses come from (issue 20, item 3): per roof kind and held-out texture, how
often one method names one of the 10 bank textures nearest the truth, which bank textures it names
most often, and how many of its misses land near the target's *other* roof.

The last count tests the guess that E2 is weak because the features cannot tell a target's flat
roofs from its sloped ones without labels. A target's flat and sloped roofs carry different
held-out textures; a flat roof inferred as one of the 10 bank flat textures nearest the target's
*sloped* texture (or the reverse) is what taking one kind's colours for the other's would give. It
is not proof of that: the two textures may look alike. So each count comes with what the same
misses would give by chance, each drawn uniformly from the bank textures outside the truth's 10
nearest.

Counts share ties as ``Ranking.credit`` does: a target whose prediction shares the 10th place counts
as that share of a hit and the rest of a miss, so miss counts may be fractional.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.errors import MetaSimError
from ..core.fileio import write_text_atomic
from ..sim.textures.pngio import write_png
from ..sim.textures.sheet import render_sheet
from .ranking import KIND_OF, OTHER_KIND, Ranking

N = 10  # top-n of the misses: E2's goal is a top-10 rate
PARAM_OF = {kind: param for param, kind in KIND_OF.items()}


def error_breakdown(targets: list[dict], ranks: dict, method: str, other_roof: dict | None = None,
                    most: int = 3) -> dict:
    """Where ``method``'s top-10 misses come from, per roof kind of the targets' space.

    ``targets`` are ``run_eval``'s ``targets_detail`` (each a ``truth`` design and ``predicted``:
    method name -> design); ``ranks`` the experiment's ``rankings``; ``other_roof`` the same
    ``rankings`` with ``across=True`` (without it, or without both roof kinds in the space, the
    other-roof counts are None); ``most`` how many of the bank textures named instead to list.

    Returns ``{"method", "targets", "kinds": {kind: summary}}``; a summary has the kind's
    ``targets``, ``top1``, ``top10`` (rates), ``misses`` (top-10 misses), ``misses_near_other_roof``
    and ``misses_near_other_roof_by_chance``, ``most_misses`` (the fewest held-out textures carrying
    at least half of the misses, with their ``share``) and ``textures``: the same per held-out
    texture, most misses first, with ``predicted``: the bank textures named most often, each with
    its ``count``, its ``place`` among the bank textures by similarity to the truth (1 = nearest,
    ties share the best place), that ``similarity`` and its ``top10`` credit.

    MetaSimError for no targets, a target without ``method``'s design, a true texture the
    rankings lack, or a predicted texture that is not one of the bank's textures of its kind.
    """
    if not targets:
        raise MetaSimError("no targets to break down: the run scored none (give --targets of at least 1)")
    for i, target in enumerate(targets):
        if method not in target["predicted"]:
            raise MetaSimError(f"target {i} has no design inferred by {method!r}; it has "
                               f"{', '.join(target['predicted']) or 'none'}")
    kinds = {}
    for param, kind in KIND_OF.items():
        if param in targets[0]["truth"]:
            across = other_roof[kind] if other_roof and PARAM_OF[OTHER_KIND[kind]] in targets[0]["truth"] else None
            kinds[kind] = _kind_breakdown(targets, kind, ranks[kind], method, across, most)
    return {"method": method, "targets": len(targets), "kinds": kinds}


def _ranking(ranks: dict, kind: str, truth: str) -> Ranking:
    try:
        return ranks[truth]
    except KeyError:
        raise MetaSimError(f"the rankings have no {kind} texture {truth!r}: give the rankings of the experiment "
                           "and held-out set the targets come from") from None


def _chance(own: Ranking, near: Ranking) -> float:
    """How near ``near``'s truth a miss of ``own``'s truth would be if drawn uniformly from the bank
    textures outside ``own``'s 10 nearest: their mean top-10 credit under ``near``, ties shared."""
    outside = [1.0 - own.credit(t, N) for t in own.ids]
    total = sum(outside)
    return sum(w * near.credit(t, N) for t, w in zip(own.ids, outside)) / total if total else 0.0


def _kind_breakdown(targets: list[dict], kind: str, ranks: dict, method: str, other_roof: dict | None,
                    most: int) -> dict:
    param, other_param = PARAM_OF[kind], PARAM_OF[OTHER_KIND[kind]]
    rows, chances = {}, {}
    for target in targets:
        truth, guess = target["truth"][param], target["predicted"][method][param]
        ranking = _ranking(ranks, kind, truth)
        if guess not in ranking.ids:
            raise MetaSimError(f"{method} named {guess!r} for a {kind} roof, not one of the bank's {kind} textures "
                               "these rankings rank: give the rankings of the bank the method searched")
        hit = ranking.credit(guess, N)
        row = rows.setdefault(truth, {"targets": 0, "top1": 0.0, "top10": 0.0, "near": 0.0, "chance": 0.0,
                                      "named": {}})
        row["targets"] += 1
        row["top1"] += ranking.credit(guess, 1)
        row["top10"] += hit
        row["named"][guess] = row["named"].get(guess, 0) + 1
        if other_roof is not None:
            other = target["truth"][other_param]
            near = _ranking(other_roof, OTHER_KIND[kind], other)
            if (truth, other) not in chances:
                chances[truth, other] = _chance(ranking, near)
            row["near"] += (1.0 - hit) * near.credit(guess, N)
            row["chance"] += (1.0 - hit) * chances[truth, other]

    def named(truth: str, counts: dict) -> list[dict]:
        ranking = ranks[truth]
        order = sorted(counts, key=lambda t: (-counts[t], ranking.place(t), t))[:most]
        return [{"id": t, "count": counts[t], "place": ranking.place(t),
                 "similarity": ranking.similarity[ranking.ids.index(t)], "top10": ranking.credit(t, N)}
                for t in order]

    textures = sorted(({"id": truth, "targets": r["targets"], "top1": r["top1"] / r["targets"],
                        "top10": r["top10"] / r["targets"], "misses": r["targets"] - r["top10"],
                        "misses_near_other_roof": r["near"] if other_roof is not None else None,
                        "misses_near_other_roof_by_chance": r["chance"] if other_roof is not None else None,
                        "distinct_named": len(r["named"]), "predicted": named(truth, r["named"])}
                       for truth, r in rows.items()), key=lambda t: (-t["misses"], t["id"]))
    misses = sum(t["misses"] for t in textures)
    carrying, total = [], 0.0
    for t in textures:
        if misses <= 0 or total >= misses / 2:
            break
        carrying.append({"id": t["id"], "misses": t["misses"], "share": t["misses"] / misses})
        total += t["misses"]

    def summed(key: str) -> float | None:
        return sum(t[key] for t in textures) if other_roof is not None else None

    return {"targets": len(targets), "top1": sum(r["top1"] for r in rows.values()) / len(targets),
            "top10": sum(r["top10"] for r in rows.values()) / len(targets), "misses": misses,
            "misses_near_other_roof": summed("misses_near_other_roof"),
            "misses_near_other_roof_by_chance": summed("misses_near_other_roof_by_chance"),
            "most_misses": carrying, "textures": textures}


def breakdown_markdown(breakdown: dict, title: str) -> str:
    """``error_breakdown``'s result as a Markdown table (one row per roof kind and held-out texture)
    and a sentence per kind, under the heading ``title``."""
    lines = [f"#### {title}: where {breakdown['method']}'s top-10 misses come from "
             f"({breakdown['targets']} target groups)", ""]
    if not breakdown["kinds"]:
        return "\n".join(lines + ["This space has no roof parameter: there is nothing to break down."]) + "\n"
    lines += ["| roof | held-out texture | targets | top-1 | top-10 | top-10 misses | of them near the other roof "
              "(by chance) | named most often: bank texture x target groups (its place by similarity to "
              "the truth, that similarity) |", "|---|---|---|---|---|---|---|---|"]
    for kind, k in breakdown["kinds"].items():
        for t in k["textures"]:
            named = "; ".join(f"{p['id']} x {p['count']} (place {p['place']}, {p['similarity']:.2f})"
                              for p in t["predicted"])
            lines.append(f"| {kind} | {t['id']} | {t['targets']} | {t['top1']:.3f} | {t['top10']:.3f} | "
                         f"{t['misses']:.1f} | {_near(t)} | {named} |")
    lines.append("")
    for kind, k in breakdown["kinds"].items():
        if k["misses"] <= 0:
            lines.append(f"{kind.capitalize()} roofs: no top-10 miss in {k['targets']} target groups.")
            continue
        carriers = ", ".join(f"{m['id']} ({m['share']:.0%})" for m in k["most_misses"])
        sentence = (f"{kind.capitalize()} roofs: {k['misses']:.1f} top-10 misses in {k['targets']} target groups; "
                    f"{len(k['most_misses'])} of {len(k['textures'])} held-out textures carry at least half of "
                    f"them: {carriers}.")
        if k["misses_near_other_roof"] is not None:
            sentence += (f" {k['misses_near_other_roof']:.1f} of the misses named one of the 10 bank {kind} "
                         f"textures nearest the target's {OTHER_KIND[kind]} roof; misses drawn uniformly from the "
                         f"bank textures outside the truth's 10 nearest would give "
                         f"{k['misses_near_other_roof_by_chance']:.1f}.")
        lines.append(sentence)
    return "\n".join(lines) + "\n"


def _near(texture: dict) -> str:
    if texture["misses_near_other_roof"] is None:
        return "-"
    return f"{texture['misses_near_other_roof']:.1f} ({texture['misses_near_other_roof_by_chance']:.1f})"


def breakdown_png(path: str | os.PathLike, breakdown: dict, swatch: Callable[[str], np.ndarray],
                  thumb: int = 176) -> Path:
    """Write a picture of ``error_breakdown``'s result to ``path``: one row per held-out texture, in the
    table's order, its swatch (labelled with the kind's initial, its name and N, its number of target
    groups) beside the bank textures named most often for it (labelled with how many groups named
    each). ``swatch`` gives a texture id's uint8 RGB image. Returns the path."""
    rows = []
    for kind, k in breakdown["kinds"].items():
        for t in k["textures"]:
            rows.append([(f"{kind[0]} {_short(t['id'], kind)} N{t['targets']}", swatch(t["id"]))]
                        + [(f"{p['count']}x {_short(p['id'], kind)}", swatch(p["id"])) for p in t["predicted"]])
    if not rows:
        raise MetaSimError("this breakdown has no roof kind: there is no texture to draw")
    return write_png(path, render_sheet(rows, thumb, max(len(row) for row in rows)))


def _short(texture_id: str, kind: str) -> str:
    """The id without its kind's prefix, so that the longest ids fit under a thumbnail."""
    return texture_id.removeprefix(f"{kind}-")


def breakdown_title(experiment: str, split: dict) -> str:
    """The heading of a breakdown of the targets of ``split`` (``Split.to_dict``)."""
    heldout = f" ({split['heldout']})" if split.get("heldout") else ""
    return f"{experiment.upper()}, {split['name']}{heldout}"


def write_breakdown(out: str | os.PathLike, results: dict, method: str, ranks: dict, other_roof: dict | None,
                    swatch: Callable[[str], np.ndarray]) -> dict:
    """``error_breakdown`` of ``run_eval``'s ``results`` for ``method``, written into the folder ``out`` as
    ``breakdown.json``, ``breakdown.md`` and ``breakdown.png`` (``swatch`` as for ``breakdown_png``).
    Returns the breakdown."""
    out = Path(out)
    breakdown = error_breakdown(results["targets_detail"], ranks, method, other_roof)
    write_text_atomic(out / "breakdown.json", json.dumps(breakdown, indent=2) + "\n")
    write_text_atomic(out / "breakdown.md",
                      breakdown_markdown(breakdown, breakdown_title(results["experiment"], results["split"])))
    breakdown_png(out / "breakdown.png", breakdown, swatch)
    return breakdown
