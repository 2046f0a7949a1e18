"""bench roof-finder's table: each training set's finder per real domain, with its training cities' range."""

from click.testing import CliRunner

from meta_sim.cli import main
from meta_sim.experiments.finder_bench import format_roof_finder_table


def _scored(flat, iou):
    return {"roof_pixels": {"flat": flat, "sloped": 0.0}, "building_share": 0.3, "iou": iou, "precision": 0.3,
            "recall": 0.95}


def test_the_table_shows_validation_and_test_beside_the_training_range():
    result = {"seconds": 120.0, "spaces": {
        "rooftops-v1": {"training_set": "abc", "training": {"quantile": 0.05, "flat": {"low": 0.006, "high": 0.25},
                                                        "sloped": {"low": 0.02, "high": 0.1}},
                        "domains": {"rio": {"validation": _scored(0.9, 0.2), "test": _scored(0.8, 0.1)}}},
        "plain": {"training_set": "def", "training": None,
                  "domains": {"kampala": {"validation": _scored(0.5, 0.5), "test": _scored(0.5, 0.4)}}}}}
    lines = format_roof_finder_table(result).splitlines()
    assert ("| rooftops-v1 | `abc` | rio | 90.0 / 80.0 [0.6-25.0] | 0.0 / 0.0 [2.0-10.0] | 30.0 / 30.0 | 20.0 / 10.0 "
            "| 30.0 / 30.0 | 95.0 / 95.0 |") in lines
    assert ("| plain | `def` | kampala | 50.0 / 50.0 | 0.0 / 0.0 | 30.0 / 30.0 | 50.0 / 40.0 | 30.0 / 30.0 "
            "| 95.0 / 95.0 |") in lines
    assert "2 min of wall time" in lines[-1]


def test_the_command_is_there_with_its_options():
    out = CliRunner().invoke(main, ["bench", "roof-finder", "--help"])
    assert out.exit_code == 0 and "--spaces" in out.output and "rooftops-v1,overhead-v2" in out.output
