"""bench-objective's protocol: the grid, the choice on validation (the default wins ties) and its table."""

import dataclasses
import json
from pathlib import Path

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.objective import (
    DEFAULT,
    FAR_DEFAULT,
    PLAIN,
    WITHOUT_FAR,
    WITHOUT_SCORE_CONE,
    Setting,
    choose,
    criterion,
    far_grid,
    format_objective_table,
    grid,
    match_grid,
)
from meta_sim.pipeline.roofcolour import SEARCH_COLOUR, SEARCH_FAR, SEARCH_FAR_MARGIN, SEARCH_MATCH


def _metrics(e1: float, e2: float) -> dict:
    keys = ("flat_top1", "flat_top10", "flat_closeness", "sloped_top1", "sloped_top10", "sloped_closeness")
    return {"e1": {k: e1 for k in keys}, "e2": {k: e2 for k in keys}}


def test_the_grid_starts_with_the_default_and_names_each_setting_once():
    settings = grid()
    assert settings[0] == DEFAULT and (DEFAULT.exponent, DEFAULT.sigma, DEFAULT.weight) == SEARCH_COLOUR
    assert (DEFAULT.far_loss, DEFAULT.match_weight, DEFAULT.far_margin, DEFAULT.match_unmix,
            DEFAULT.match_rendered) == SEARCH_MATCH
    assert DEFAULT.matches
    assert DEFAULT.far is None and settings[1] == WITHOUT_FAR and WITHOUT_FAR.far is None
    assert FAR_DEFAULT.far == SEARCH_FAR and FAR_DEFAULT.far_margin == SEARCH_FAR_MARGIN and not FAR_DEFAULT.matches
    assert all(s.far_loss is None for s in settings[1:])  # the far-target searches are far_grid's and match_grid's
    assert PLAIN in settings and PLAIN.comparison().blur is None and PLAIN.score_cone
    assert len({s.name for s in settings}) == len(settings)
    assert Setting(0.3, 1.5, 30.0).name == "exponent 0.3, blur 1.5 bins x 30"
    assert Setting(0.3, 1.5, 30.0).comparison().blur.shape == (488, 488)
    assert Setting(0.3, 1.5, 30.0).comparison((488, 488, 220, 220)).blur.shape == (1416, 1416)
    # Both models: with the score cone (the default) and without, each with every comparison.
    assert DEFAULT.score_cone and WITHOUT_SCORE_CONE in settings
    assert sum(s.score_cone for s in settings[1:]) == sum(not s.score_cone for s in settings) == len(settings) // 2
    assert WITHOUT_SCORE_CONE.name == "exponent 0.5, no blur, no score cone"


def test_the_far_grid_adds_every_far_comparison_to_one_setting():
    main = Setting(0.3, 1.0, 30.0)
    fars = far_grid(main, losses=(3.0, 4.0), exponents=(0.5,), weights=(0.0, 10.0), margins=(None,))
    assert len(fars) == 4 and all((s.exponent, s.sigma, s.weight, s.score_cone) == (0.3, 1.0, 30.0, True)
                                  for s in fars)
    assert fars[1].name == "exponent 0.3, blur 1 bins x 30; beyond 3: score cone, exponent 0.5, blur 1 x 10"
    assert fars[0].name.endswith("beyond 3: score cone, exponent 0.5, no blur")
    assert fars[1].comparison((488, 488, 220, 220)).far_loss == 3.0
    assert fars[1].comparison((488, 488, 220, 220)).far.keep.sum() == 440
    assert len({s.name for s in far_grid(main)}) == len(far_grid(main))
    # With a margin: the first answer kept where the far comparison finds it within 10% of its best.
    gated = far_grid(main, losses=(4.0,), exponents=(0.5,), weights=(10.0,), margins=(None, 0.1))
    assert [s.far_margin for s in gated] == [None, 0.1]
    assert gated[1].name == gated[0].name + ", unless the first answer is within 10%"
    assert gated[1].comparison((488, 488, 220, 220)).far_margin == 0.1
    assert gated[0].comparison((488, 488, 220, 220)).far_margin is None
    assert Setting(0.3, far_margin=0.1).comparison().far_margin is None  # no far search, no margin


def test_the_match_grid_ranks_far_targets_by_every_roof_match():
    main = Setting(0.3, 1.0, 30.0)
    matches = match_grid(main, losses=(10.0,), weights=(0.0, 0.7), margins=(None, 0.05), unmixes=(0.0,),
                         rendered=(0.0,))
    assert [(s.far_loss, s.match_weight, s.far_margin) for s in matches] == \
        [(10.0, 0.0, None), (10.0, 0.0, 0.05), (10.0, 0.7, None), (10.0, 0.7, 0.05)]
    assert all(s.matches and s.far is None and (s.exponent, s.sigma, s.weight) == (0.3, 1.0, 30.0) for s in matches)
    assert matches[3].name == ("exponent 0.3, blur 1 bins x 30; beyond 10: roof match, swatch weight 0.7, unless the "
                               "first answer is within 5%")
    assert len({s.name for s in match_grid(main)} | {s.name for s in far_grid(main)}) == \
        len(match_grid(main)) + len(far_grid(main))
    # Unmixing only where the swatches count (it acts on their part alone).
    unmixed = match_grid(main, losses=(10.0,), weights=(0.0, 0.7), margins=(None,), unmixes=(0.0, 0.5),
                         rendered=(0.0,))
    assert [(s.match_weight, s.match_unmix) for s in unmixed] == [(0.0, 0.0), (0.7, 0.0), (0.7, 0.5)]
    assert unmixed[2].name.endswith("roof match, swatch weight 0.7, unmixed x 0.5")
    # Render shares likewise.
    shared = match_grid(main, losses=(10.0,), weights=(0.0, 1.0), margins=(None,), unmixes=(0.5,),
                        rendered=(0.0, 0.25))
    assert [(s.match_weight, s.match_unmix, s.match_rendered) for s in shared] == [(1.0, 0.5, 0.0), (1.0, 0.5, 0.25)]
    assert shared[1].name.endswith("swatch weight 1, unmixed x 0.5, 0.25 as rendered")
    with pytest.raises(MetaSimError, match="needs a checkpoint"):
        matches[0].comparison((488, 488, 220, 220))


def test_the_choice_is_the_best_mean_of_the_four_targets_and_the_default_wins_ties():
    assert criterion(_metrics(1.0, 0.5)) == 0.75
    rows = [{"name": "default", "criterion": 0.75}, {"name": "a", "criterion": 0.75}, {"name": "b", "criterion": 0.7}]
    assert choose(rows)["name"] == "default"
    rows.append({"name": "c", "criterion": 0.76})
    assert choose(rows)["name"] == "c"


def test_a_setting_replaces_the_default_only_when_its_paired_gain_is_more_than_resampling_shows(monkeypatch):
    """``paired_gain`` on made-up score rows (``_rows`` stands in for the search): a challenger better on every
    group of both experiments gains with an interval above 0; one that gains only on a single E2 texture out of
    three (and is as good elsewhere) has an interval reaching 0, so the default would stay; the table says
    which."""
    import numpy as np

    from meta_sim.experiments import objective

    rng = np.random.default_rng(0)

    def rows(e1_hits, e2_hits, textures):
        e1 = [{"flat_top1": float(h), "sloped_top1": float(h)} for h in e1_hits]
        e2 = [{"flat_top10": float(h), "sloped_top10": float(h)} for h in e2_hits]
        truth = [{"flat_roof": t, "sloped_roof": t} for t in textures]
        return {"e1": (e1, [{}] * len(e1)), "e2": (e2, truth)}

    textures = [f"held-{i % 3}" for i in range(90)]
    base_e1, base_e2 = rng.random(90) < 0.7, rng.random(90) < 0.6
    results = {"default": rows(base_e1, base_e2, textures),
               "better": rows(np.ones(90), np.ones(90), textures),
               "one texture": rows(base_e1, base_e2 | (np.array(textures) == "held-0"), textures)}
    monkeypatch.setattr(objective, "_rows", lambda setting, data: results[setting])
    better = objective.paired_gain("default", "better", None)
    assert better["gain"] > 0.2 and better["interval"][0] > 0
    narrow = objective.paired_gain("default", "one texture", None)
    assert narrow["gain"] > 0 and narrow["interval"][0] <= 0 < narrow["interval"][1]
    assert objective.paired_gain("default", "default", None) == {"gain": 0.0, "interval": [0.0, 0.0]}


def test_the_table_reports_the_default_and_the_chosen_setting_on_test_beside_validation():
    default, chosen = Setting(), Setting(0.3, 1.5, 30.0)
    validation = [{"setting": vars(s), "name": s.name, "metrics": _metrics(*m), "criterion": criterion(_metrics(*m))}
                  for s, m in ((default, (0.9, 0.5)), (chosen, (0.9, 0.7)))]
    test = {label: {"setting": vars(s), "name": s.name, "metrics": _metrics(*m), "criterion": criterion(_metrics(*m))}
            for label, s, m in (("default", default, (0.8, 0.4)), ("chosen", chosen, (0.85, 0.45)),
                                ("without score cone", WITHOUT_SCORE_CONE, (0.8, 0.3)))}
    validation.append({"setting": vars(WITHOUT_SCORE_CONE), "name": WITHOUT_SCORE_CONE.name,
                       "metrics": _metrics(0.9, 0.4), "criterion": criterion(_metrics(0.9, 0.4))})
    test["chosen"]["metrics"]["e2"]["intervals"] = {"flat_top10": [0.4, 0.5]}
    split = {"e1": {"seeds": [1, 2, 7]}, "e2": {"seeds": [1, 2, 7], "heldout": "heldout-v1"}}
    result = {"validation": validation, "test": test, "targets_per_seed": 100,
              "splits": {"validation": split, "test": {"e1": {"seeds": [21]}, "e2": {"seeds": [21], "heldout": "v2"}}}}
    table = format_objective_table(result)
    lines = table.splitlines()
    assert lines[2].startswith("| default: exponent 0.5, no blur | test | 0.800")
    assert "| chosen: exponent 0.3, blur 1.5 bins x 30 | test |" in table and "0.450 [0.400, 0.500]" in table
    # The chosen setting's validation row: no target searched as far; the mean of 0.9, 0.9, 0.7, 0.7.
    assert lines[5].endswith("| 0.00 / 0.00 | 0.800 |")
    assert "validation #1: exponent 0.3, blur 1.5 bins x 30" in table and "`v2`" in table
    assert "| without score cone: exponent 0.5, no blur, no score cone | test | 0.800" in table
    assert "| check |" not in table and "check seeds" not in table  # a result from before the check split
    result["check"] = {"default": {**test["default"], "criterion": 0.5}}
    result["splits"]["check"] = {"e1": {"seeds": [31]}, "e2": {"seeds": [31], "heldout": "heldout-v3"}}
    lines = format_objective_table(result).splitlines()
    assert lines[3].startswith("| default: exponent 0.5, no blur | check |") and lines[3].endswith("| 0.500 |")
    assert "Best on validation" not in table  # a result from before the adoption rule
    result["test"]["best"] = result["test"].pop("chosen")
    result["best"] = {"name": chosen.name, "gain_over_default": {"gain": 0.1, "interval": [-0.01, 0.2]},
                      "adopted": False}
    table = format_objective_table(result)
    assert "| best on validation: exponent 0.3, blur 1.5 bins x 30 | test |" in table
    result["check"]["best"] = {**test["best"], "criterion": 0.6}
    assert "| best on validation: exponent 0.3, blur 1.5 bins x 30 | check |" in format_objective_table(result)
    assert ("Best on validation: exponent 0.3, blur 1.5 bins x 30, +0.100 over the default in the mean of the four "
            "[-0.010, +0.200]") in table and "not adopted: the default stays" in table
    assert "check seeds 31 and E2 on `heldout-v3`" in lines[-1]
    del result["test"]["without score cone"]  # a result from before the score cone
    assert "without score cone" not in format_objective_table(result).split("validation #1")[0]


def test_the_command_is_there_with_the_options_of_a_bench_on_bench_nams_targets():
    from click.testing import CliRunner

    from meta_sim.cli import main

    out = CliRunner().invoke(main, ["bench", "objective", "--help"])
    assert out.exit_code == 0
    assert all(option in out.output for option in ("--docs", "--targets", "--cache", "benchmarks/objective.json"))


def test_the_search_defaults_are_the_setting_the_published_bench_objective_run_chose():
    """`make bench-objective` names the setting it chose (adopted, or the default it kept); the code's defaults
    (`roofcolour.SEARCH_COLOUR`, `SEARCH_MATCH`) must be that setting, or the published figures are not the
    defaults'."""
    published = json.loads((Path(__file__).resolve().parents[2] / "benchmarks" / "objective.json").read_text())
    assert dataclasses.asdict(DEFAULT) == published["chosen"]
