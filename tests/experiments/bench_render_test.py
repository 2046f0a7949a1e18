"""bench-render times the default scene and the richer one of real targets' space."""

from meta_sim.experiments.bench import RICH_SPACE, bench_render, format_render_table


def test_render_bench_times_both_scenes_and_tables_them():
    result = bench_render(designs=1, tiles=1, repeats=1, presets=("fast",))
    for costs in (result, result["rich"]):
        fast = costs["presets"]["fast"]
        assert 0 < fast["render_seconds_per_tile"] <= fast["seconds_per_tile"] <= fast["wall_seconds_per_tile"]
        assert costs["city_build_seconds"] > 0
    assert result["rich"]["space"] == RICH_SPACE
    table = format_render_table(result)
    assert "| rooftops-v1 | fast |" in table and f"| {RICH_SPACE} | fast |" in table
