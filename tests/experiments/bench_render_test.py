"""bench-render times the default scene, the richer one of real targets' space and the city layouts alone."""

from meta_sim.experiments.bench import LAYOUT_CASES, RICH_SPACE, bench_render, format_render_table


def test_render_bench_times_both_scenes_and_tables_them():
    tiny = {name: (60.0, 50.0, knobs) for name, (_, _, knobs) in LAYOUT_CASES.items()}  # every case's knobs
    result = bench_render(designs=1, tiles=1, repeats=1, presets=("fast",), layouts=tiny)
    for costs in (result, result["rich"]):
        fast = costs["presets"]["fast"]
        assert 0 < fast["render_seconds_per_tile"] <= fast["seconds_per_tile"] <= fast["wall_seconds_per_tile"]
        assert costs["city_build_seconds"] > 0
    assert result["rich"]["space"] == RICH_SPACE
    assert list(result["layout_seconds"]) == list(LAYOUT_CASES)
    for name, case in result["layout_seconds"].items():
        assert (case["width_m"], case["height_m"], case["knobs"]) == tiny[name] and case["seconds"] > 0
    table = format_render_table(result)
    assert "| rooftops-v1 | fast |" in table and f"| {RICH_SPACE} | fast |" in table
    assert all(f"{name} " in table.splitlines()[-1] for name in LAYOUT_CASES)
