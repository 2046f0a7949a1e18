"""`make bench-stability`: every extreme case ends in a finite preset or a clear error, and the table says
which; a case that ends otherwise is caught."""

import math

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.stability import (
    ERROR,
    FINITE,
    UNSTABLE,
    Case,
    _finite_results,
    _outcome,
    bench_stability,
    check,
    format_stability_table,
)
from meta_sim.sim.design import DesignSpace

# Issue 20, item 6: the cases the table must hold.
CASES = ("constant grey target", "black target", "white target", "HDR target", "NaN and Inf pixels", "NaN target",
         "one-tile groups", "M=1", "S=M", "k=0", "r=0", "r=1", "bfloat16", "one-choice space, exhaustive",
         "one-choice space, adjoint", "zero-variance features (every dimension)",
         "zero-variance features (every other dimension)")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    return bench_stability(tmp_path_factory.mktemp("stability"))


def test_every_extreme_case_ends_in_a_finite_preset_or_a_clear_error(result):
    outcomes = {c["case"]: c for c in result["cases"]}
    assert tuple(outcomes) == CASES
    check(result)
    for case in outcomes.values():
        assert case["ended"] in (FINITE, ERROR), case
        if case["ended"] == FINITE:
            assert case["designs"] and all(loss is None or math.isfinite(loss) for loss in case["losses"])
    # Nothing to learn from: said so, before any training.
    assert outcomes["zero-variance features (every dimension)"]["ended"] == ERROR
    assert "no feature tells one design from another" in outcomes["zero-variance features (every dimension)"]["detail"]
    assert len(outcomes["one-tile groups"]["designs"]) == 4  # one preset per tile
    only = outcomes["one-choice space, exhaustive"]["designs"][0]
    assert outcomes["one-choice space, adjoint"]["designs"] == [only]  # the space's one design, both ways
    table = format_stability_table(result)
    assert table.count("\n| ") == len(CASES) and "| NaN target | " in table and "tile of 96 px" in table


def test_a_case_that_ends_otherwise_is_unstable_and_fails_the_check():
    def crash():
        raise ZeroDivisionError("float division by zero")

    def refuse():
        raise MetaSimError("-M must be at least 1")

    crashed = _outcome(Case("crash", "search", "a crash", crash))
    assert crashed["ended"] == UNSTABLE and "ZeroDivisionError: float division by zero" in crashed["detail"]
    assert _outcome(Case("refused", "search", "bad options", refuse))["ended"] == ERROR
    with pytest.raises(MetaSimError, match="unstable at the extremes: crash: ZeroDivisionError"):
        check({"cases": [crashed]})
    space = DesignSpace.load()
    design = {name: space.parameter(name).choices[0] for name in ("flat_roof", "sloped_roof")}
    assert _finite_results([design], [0.5], space)["ended"] == FINITE
    assert _finite_results([design, design], [0.5, math.nan], space)["ended"] == UNSTABLE  # a silent NaN
    assert _finite_results([{**design, "flat_roof": "flat-nowhere"}], [0.5], space)["ended"] == UNSTABLE
