"""bench-exposure: the fast preset's exposure from the two presets' renders of the same training designs."""

from click.testing import CliRunner

from meta_sim.cli import main as cli
from meta_sim.experiments.exposure import bench_exposure, format_exposure_table
from meta_sim.sim.quality import FAST_EXPOSURE


def test_the_measured_exposure_is_the_one_in_use_and_is_tabled():
    """On a few training designs the flat roofs' brightness ratio lands near FAST_EXPOSURE (the full run's
    quartiles span about +-0.5 around it), and sloped roofs and the ground come out in the same range."""
    result = bench_exposure(designs=4, tiles=1)
    flat = result["ratios"]["flat roofs"]
    assert flat["tiles"] >= 3 and flat["q1"] <= flat["median"] <= flat["q3"]
    assert abs(flat["median"] - FAST_EXPOSURE) < 1.0, result
    for part in ("sloped roofs", "ground"):
        assert 2.0 < result["ratios"][part]["median"] < 5.0, result
    assert result["in_use"] == FAST_EXPOSURE and result["measured"] == round(flat["median"], 1)
    table = format_exposure_table(result)
    assert "| flat roofs |" in table and f"{FAST_EXPOSURE:g} in use" in table


def test_the_exposure_bench_refuses_an_empty_run(tmp_path):
    outcome = CliRunner().invoke(cli, ["bench", "exposure", "--designs", "0", "--out", str(tmp_path / "x.json"),
                                       "--no-docs"])
    assert outcome.exit_code != 0 and "--designs and --tiles must be at least 1" in outcome.output
    assert not (tmp_path / "x.json").exists()
