"""Where E2's misses come from: counts, rates and the other-roof count on hand-made rankings."""

import json
import struct

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.breakdown import breakdown_markdown, breakdown_png, error_breakdown, write_breakdown
from meta_sim.experiments.ranking import Ranking

FLAT = tuple(f"flat-{c}" for c in "abcdefghijklm")  # 13 bank flat textures
SLOPED = tuple(f"sloped-{c}" for c in "abcdefghijkl")  # 12 bank sloped textures


def _ranking(order, ids):
    """A ranking of ``ids`` in the order of the indices ``order``, with distinct similarities."""
    return Ranking(tuple(ids[i] for i in order), tuple(round(0.9 - 0.05 * k, 2) for k in range(len(order))))


def _ranks():
    ranks = {"flat": {"flat-held-1": _ranking(range(13), FLAT),  # a..j are its 10 nearest; k, l, m are not
                      "flat-held-2": _ranking([10, *range(10), 11, 12], FLAT)},  # k is its nearest
             "sloped": {"sloped-held-1": _ranking(range(12), SLOPED)}}  # a..j near; k, l not
    # The bank textures of each kind by similarity to the targets' other roof.
    other_roof = {"flat": {"sloped-held-1": _ranking([10, *range(9), 11, 12, 9], FLAT)},  # k near; l, m not
                  "sloped": {"flat-held-1": _ranking([10, *range(10), 11], SLOPED),  # k near; l not
                             "flat-held-2": _ranking(range(12), SLOPED)}}
    return ranks, other_roof


def _target(flat_truth, flat_guess, sloped_guess, method="nams_exhaustive"):
    return {"truth": {"flat_roof": flat_truth, "sloped_roof": "sloped-held-1"},
            "predicted": {method: {"flat_roof": flat_guess, "sloped_roof": sloped_guess},
                          "uniform": {"flat_roof": "flat-m", "sloped_roof": "sloped-l"}}}


TARGETS = [
    _target("flat-held-1", "flat-a", "sloped-a"),  # both top-1
    _target("flat-held-1", "flat-k", "sloped-k"),  # both miss, each near the other roof
    _target("flat-held-1", "flat-l", "sloped-b"),  # flat misses, not near the sloped roof; sloped top-10
    _target("flat-held-2", "flat-k", "sloped-a"),  # flat-k is flat-held-2's nearest: top-1
]


def test_rates_misses_and_the_bank_textures_named_per_held_out_texture():
    ranks, other_roof = _ranks()
    result = error_breakdown(TARGETS, ranks, "nams_exhaustive", other_roof)
    assert result["method"] == "nams_exhaustive" and result["targets"] == 4
    flat = result["kinds"]["flat"]
    assert (flat["targets"], flat["top1"], flat["top10"], flat["misses"]) == (4, 0.5, 0.5, 2.0)
    held1, held2 = flat["textures"]  # most misses first
    assert held1["id"] == "flat-held-1" and held1["targets"] == 3 and held1["misses"] == 2.0
    assert held1["top1"] == pytest.approx(1 / 3) and held1["top10"] == pytest.approx(1 / 3)
    assert (held2["id"], held2["targets"], held2["top1"], held2["top10"], held2["misses"]) == (
        "flat-held-2", 1, 1.0, 1.0, 0.0)
    # Each named once: the nearest first; place and similarity are those under the truth's ranking.
    assert [(p["id"], p["count"], p["place"], p["top10"]) for p in held1["predicted"]] == [
        ("flat-a", 1, 1, 1.0), ("flat-k", 1, 11, 0.0), ("flat-l", 1, 12, 0.0)]
    assert held1["predicted"][1]["similarity"] == pytest.approx(0.4)
    assert flat["most_misses"] == [{"id": "flat-held-1", "misses": 2.0, "share": 1.0}]
    sloped = result["kinds"]["sloped"]
    assert (sloped["targets"], sloped["top1"], sloped["top10"], sloped["misses"]) == (4, 0.5, 0.75, 1.0)
    assert [(p["id"], p["count"]) for p in sloped["textures"][0]["predicted"]] == [
        ("sloped-a", 2), ("sloped-b", 1), ("sloped-k", 1)]


def test_misses_near_the_other_roof_are_counted_against_chance():
    ranks, other_roof = _ranks()
    result = error_breakdown(TARGETS, ranks, "nams_exhaustive", other_roof)
    flat, sloped = result["kinds"]["flat"], result["kinds"]["sloped"]
    # Of flat-held-1's two misses only flat-k is among the sloped roof's 10 nearest flat textures. By
    # chance: one of the three textures outside flat-held-1's 10 nearest (k, l, m) is, per miss.
    assert flat["misses_near_other_roof"] == 1.0
    assert flat["misses_near_other_roof_by_chance"] == pytest.approx(2 / 3)
    assert flat["textures"][0]["misses_near_other_roof"] == 1.0
    # The sloped miss sloped-k is among the 10 nearest of that target's flat roof; chance: one of k, l.
    assert sloped["misses_near_other_roof"] == 1.0
    assert sloped["misses_near_other_roof_by_chance"] == pytest.approx(0.5)
    # Without the other-roof rankings those counts are left out, the rest is the same.
    alone = error_breakdown(TARGETS, ranks, "nams_exhaustive")
    assert alone["kinds"]["flat"]["misses_near_other_roof"] is None
    assert alone["kinds"]["flat"]["misses"] == 2.0


def test_a_tie_at_the_tenth_place_counts_as_a_share_of_a_miss():
    ids = tuple(f"flat-{c}" for c in "abcdefghijkl")
    tied = Ranking(ids, (0.9, 0.8, 0.7, 0.6, 0.5, 0.4, 0.3, 0.2, 0.0, 0.0, 0.0, 0.0))  # 4 share places 9, 10
    targets = [{"truth": {"flat_roof": "flat-held"}, "predicted": {"m": {"flat_roof": "flat-l"}}}]
    flat = error_breakdown(targets, {"flat": {"flat-held": tied}}, "m")["kinds"]["flat"]
    assert flat["top10"] == 0.5 and flat["misses"] == 0.5
    assert flat["textures"][0]["predicted"][0]["place"] == 9
    assert flat["misses_near_other_roof"] is None  # the space has no sloped roof


def test_bad_input_gives_a_clear_error():
    ranks, other_roof = _ranks()
    with pytest.raises(MetaSimError, match="no targets"):
        error_breakdown([], ranks, "nams_exhaustive", other_roof)
    with pytest.raises(MetaSimError, match="no design inferred by 'nams_adjoint'"):
        error_breakdown(TARGETS, ranks, "nams_adjoint", other_roof)
    with pytest.raises(MetaSimError, match="no flat texture 'flat-held-3'"):
        error_breakdown([_target("flat-held-3", "flat-a", "sloped-a")], ranks, "nams_exhaustive")
    with pytest.raises(MetaSimError, match="not one of the bank's flat textures"):
        error_breakdown([_target("flat-held-1", "sloped-a", "sloped-a")], ranks, "nams_exhaustive")


def test_markdown_has_a_row_per_held_out_texture_and_a_sentence_per_kind():
    ranks, other_roof = _ranks()
    text = breakdown_markdown(error_breakdown(TARGETS, ranks, "nams_exhaustive", other_roof), "E2, validation")
    lines = text.splitlines()
    assert lines[0] == "#### E2, validation: where nams_exhaustive's top-10 misses come from (4 target groups)"
    rows = [line for line in lines if line.startswith("| flat") or line.startswith("| sloped")]
    assert len(rows) == 3
    assert rows[0] == ("| flat | flat-held-1 | 3 | 0.333 | 0.333 | 2.0 | 1.0 (0.7) | flat-a x 1 (place 1, 0.90); "
                       "flat-k x 1 (place 11, 0.40); flat-l x 1 (place 12, 0.35) |")
    assert "Flat roofs: 2.0 top-10 misses in 4 target groups; 1 of 2 held-out textures carry at least half of " \
           "them: flat-held-1 (100%). 1.0 of the misses named one of the 10 bank flat textures nearest the " \
           "target's sloped roof;" in text
    no_roofs = breakdown_markdown({"method": "dr", "targets": 2, "kinds": {}}, "E2")
    assert "no roof parameter" in no_roofs and "|" not in no_roofs


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_the_picture_has_a_row_per_held_out_texture_beside_the_textures_named(tmp_path):
    from meta_sim.sim.imageio import read_rgb8

    ranks, other_roof = _ranks()
    result = error_breakdown(TARGETS, ranks, "nams_exhaustive", other_roof)
    colours = {}

    def swatch(texture_id):  # a colour of its own per texture
        colour = colours.setdefault(texture_id, np.array([len(colours) * 20, 100, 200], dtype=np.uint8))
        return np.broadcast_to(colour, (24, 40, 3)).copy()

    path = breakdown_png(tmp_path / "breakdown.png", result, swatch, thumb=32)
    # 3 held-out textures (rows) x (the truth + at most 3 named): 4 px padding, 11 px label strips.
    assert _png_size(path) == (4 + 4 * (32 + 4), 4 + 3 * (32 + 11 + 4))
    image = read_rgb8(path)
    assert (image[20, 20] == colours["flat-held-1"]).all()  # the first row starts with its truth
    assert (image[20, 4 + 36 + 16] == colours["flat-a"]).all()  # beside the texture named most
    with pytest.raises(MetaSimError, match="no roof kind"):
        breakdown_png(tmp_path / "none.png", {"kinds": {}}, swatch)


def test_write_breakdown_writes_json_markdown_and_picture(tmp_path):
    ranks, other_roof = _ranks()
    results = {"experiment": "e2", "split": {"name": "validation", "heldout": "heldout-v1"}, "targets_detail": TARGETS}
    breakdown = write_breakdown(tmp_path, results, "nams_exhaustive", ranks, other_roof,
                                lambda texture_id: np.zeros((8, 8, 3), np.uint8))
    assert json.loads((tmp_path / "breakdown.json").read_text()) == breakdown
    assert (tmp_path / "breakdown.md").read_text().startswith("#### E2, validation (heldout-v1): where nams_exhaustive")
    assert _png_size(tmp_path / "breakdown.png")[0] > 0


def test_other_roof_rankings_rank_a_kinds_bank_textures_by_the_other_roofs_texture(bank, heldout_bank):
    from meta_sim.experiments.ranking import rankings

    across = rankings("e2", bank, heldout_bank, across=True)
    for kind, other in (("flat", "sloped"), ("sloped", "flat")):
        assert set(across[kind]) == set(heldout_bank.ids(other))
        for ranking in across[kind].values():
            assert sorted(ranking.ids) == sorted(bank.ids(kind))
            assert list(ranking.similarity) == sorted(ranking.similarity, reverse=True)


def test_bench_nams_table_gives_each_splits_breakdown_after_the_accuracy_table():
    from meta_sim.experiments.bench import format_nams_table
    from meta_sim.experiments.splits import get_split

    ranks, other_roof = _ranks()
    breakdown = error_breakdown(TARGETS, ranks, "nams_exhaustive", other_roof)
    row = {"flat_top1": 0.5, "flat_top10": 0.5, "sloped_top1": 0.5, "sloped_top10": 0.75, "seconds_per_target": 0.01,
           "targets": 4}
    result = {"splits": {name: {"settings": {e: get_split(e, name).to_dict() for e in ("e1", "e2")},
                                "experiments": {"e2": {"nams_exhaustive": row}}, "breakdown": {"e2": breakdown}}
                         for name in ("validation", "test")},
              "targets_per_seed": 4, "adjoint_targets": 1, "tiles_per_target": 9, "architecture": "additive",
              "train_seconds_other_architectures": {}, "dataset": {"designs": 600, "tiles": 2, "preset": "fast"},
              "feature_seconds_per_group": 0.2, "fastest_adjoint_keeping_e1": {"M": 250, "iterations": 200}}
    table = format_nams_table(result)
    test = table.index("#### E2, test (heldout-v2): where nams_exhaustive's top-10 misses come from")
    validation = table.index("#### E2, validation (heldout-v5): where nams_exhaustive's top-10 misses come from")
    assert table.index("| E2 | nams_exhaustive | test |") < test < validation  # test first, as in the table above
    assert table.count("| flat | flat-held-1 | 3 | 0.333 | 0.333 | 2.0 | 1.0 (0.7) |") == 2
    del result["splits"]["test"]["breakdown"]  # a result from before the breakdown
    assert "misses come from" in format_nams_table(result) and "E2, test (" not in format_nams_table(result)
