"""Validation and test splits of E1 and E2: disjoint targets, the held-out set of each, and the
defaults chosen by measurement naming where they were chosen."""

import importlib
import re
from pathlib import Path

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.evaluate import EvalSettings, target_jobs
from meta_sim.experiments.splits import (
    GROUPS_PER_SEED,
    MEASURED_DEFAULTS,
    SPLITS,
    get_split,
    single_seed,
    spread,
)
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.textures import ensure_heldout_bank

DESIGN_DOC = Path(__file__).resolve().parents[2] / "docs" / "design.md"


def test_validation_holds_the_seed_choices_were_made_on_and_test_is_disjoint_from_it():
    for experiment in ("e1", "e2"):
        validation, test = get_split(experiment, "validation"), get_split(experiment, "test")
        assert 1 in validation.seeds  # bench-nams's targets before the splits: where every choice was made
        assert len(test.seeds) >= 3 and not set(test.seeds) & set(validation.seeds)
        assert test.touches_test and not validation.touches_test
    assert get_split("e1", "test").heldout is None
    assert (get_split("e2", "validation").heldout, get_split("e2", "test").heldout) == ("heldout-v5", "heldout-v2")
    assert set(SPLITS) == {(e, s) for e in ("e1", "e2") for s in ("validation", "test", "check")}
    assert get_split("e2", "check").heldout == "heldout-v3" and get_split("e1", "check").touches_test
    assert not set(get_split("e1", "check").seeds) & (set(get_split("e1", "test").seeds)
                                                      | set(get_split("e1", "validation").seeds))
    with pytest.raises(MetaSimError, match="unknown split 'train'"):
        get_split("e1", "train")
    with pytest.raises(MetaSimError, match="unknown experiment 'e3'"):
        get_split("e3", "test")


def test_no_target_city_or_design_of_a_test_split_is_a_validation_one(bank):
    space = DesignSpace.load()
    for experiment in ("e1", "e2"):
        cities = {}
        for name in ("validation", "test", "check"):
            split = get_split(experiment, name)
            held = ensure_heldout_bank(name=split.heldout or "heldout-v1")
            jobs = [job for seed in split.seeds for job in target_jobs(experiment, space, held, 100, seed)]
            cities[name] = {job.city_seed for job in jobs}
            assert len(cities[name]) == len(jobs) == 100 * len(split.seeds)  # no two groups share a city
            if experiment == "e2":
                assert {job.design["flat_roof"] for job in jobs} <= set(held.ids("flat"))
                assert {job.design["sloped_roof"] for job in jobs} <= set(held.ids("sloped"))
        assert not cities["validation"] & cities["test"]
        assert not cities["check"] & (cities["validation"] | cities["test"])


def test_more_groups_per_seed_than_a_seed_has_cities_is_refused():
    split = get_split("e1", "test")
    assert split.check(GROUPS_PER_SEED) is split
    with pytest.raises(MetaSimError, match=f"at most {GROUPS_PER_SEED} target groups per seed"):
        split.check(GROUPS_PER_SEED + 1)
    with pytest.raises(MetaSimError, match="at most"):
        EvalSettings(targets=GROUPS_PER_SEED + 1, split=split).check()
    single_seed("e1", 5).check(GROUPS_PER_SEED + 1)  # one seed has no neighbour to overlap


def test_a_single_seed_says_which_split_it_belongs_to():
    assert single_seed("e1", 1).name == "seed 1, of the validation split"
    assert single_seed("e2", 22).touches_test and single_seed("e2", 22).name == "seed 22, of the test split"
    assert single_seed("e2", 5, "heldout-v2").touches_test  # the test textures, whatever the seed
    assert single_seed("e1", 5).name == "seed 5" and not single_seed("e1", 5).touches_test
    assert single_seed("e1", 31).name == "seed 31, of the check split"
    assert single_seed("e2", 5, "heldout-v3").touches_test  # the check textures, whatever the seed
    assert single_seed("e2", 1).heldout == "heldout-v1" and single_seed("e1", 1).heldout is None
    assert single_seed("e2", 1).name == "seed 1"  # heldout-v1 is no split's set since validation moved on
    assert single_seed("e2", 1, "heldout-v5").name == "seed 1, of the validation split"
    assert single_seed("e2", 1, "heldout-v4").name == "seed 1"  # the validation set of one day, part of v5
    for bad in (-1, 1.5, True):
        with pytest.raises(MetaSimError, match="target seed"):
            single_seed("e1", bad)


def test_eval_settings_use_the_split_of_their_experiment_or_one_seed():
    assert EvalSettings(seed=7).target_split("e2") == single_seed("e2", 7)
    split = get_split("e2", "test")
    assert EvalSettings(split=split).target_split("e2") is split
    with pytest.raises(MetaSimError, match="is E2's, not E1's"):
        EvalSettings(split=split).target_split("e1")


def test_spread_takes_groups_from_every_seed_in_turn():
    assert spread(3, 4, 5) == [0, 1, 4, 5, 8]
    assert spread(3, 4, 100) == list(range(12))
    assert spread(1, 4, 2) == [0, 1]


def test_every_default_chosen_by_measurement_exists_and_design_md_names_its_split():
    text = DESIGN_DOC.read_text()
    section = text[text.index("## Splits"):]
    section = section[:section.find("\n## ", 1)] if "\n## " in section[1:] else section
    for label, (location, chosen_on) in MEASURED_DEFAULTS.items():
        module, _, attribute = location.partition(":")
        value = importlib.import_module(module)
        for part in attribute.split("."):
            value = getattr(value, part)  # a renamed default fails here: update the table and the docs
        row = next((line for line in section.splitlines() if line.startswith(f"| {label} |")), None)
        assert row is not None, f"docs/design.md, Splits: no row for {label!r}"
        assert re.search(rf"\| {re.escape(chosen_on)} \|", row), (label, row)
