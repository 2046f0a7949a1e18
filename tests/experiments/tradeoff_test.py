"""The speed/accuracy report: profiles, table and plot from a measured-shaped result."""

import json

import numpy as np
import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.tradeoff import accuracy, format_tradeoff_table, plot_tradeoff
from meta_sim.pipeline.dataset import DatasetConfig
from meta_sim.pipeline.profiles import PROFILES, get_profile
from meta_sim.sim.imageio import read_rgb8


def _result():
    def point(knob, setting, top1, seconds, one_off):
        metrics = {"flat_top1": top1, "flat_top10": 1.0, "sloped_top1": top1 - 0.1, "sloped_top10": 0.9}
        return {"knob": knob, "setting": setting, "metrics": metrics, "seconds_per_group": seconds,
                "one_off_seconds": one_off, "targets": 10, "detail": {}}

    return {"experiment": "e1", "targets": 10, "adjoint_targets": 5,
            "views": {"max_abs_difference_1_vs_8_views": 1e-7, "seconds_per_9_tiles_1_view": 0.1,
                      "seconds_per_9_tiles_8_views_if_not_invariant": 0.8},
            "points": [point("tiles per target group", "1", 0.5, 0.01, 300),
                       point("tiles per target group", "9", 0.9, 0.09, 300),
                       point("search", "adjoint M=1000, 200 it", 0.85, 16.0, 300),
                       point("training set", "600 x 4", 0.95, 0.09, 700),
                       point("render preset", "balanced", 0.9, 0.09, 900),
                       point("profile", "fast", 0.9, 0.09, 300)]}


def test_profiles_are_the_three_recommended_ones_and_unknown_names_are_clear_errors():
    assert list(PROFILES) == ["fast", "balanced", "paper"]
    paper = get_profile("paper")
    assert (paper.dataset.designs, paper.dataset.tiles, paper.views, paper.method) == (1700, 9, 8, "adjoint")
    assert paper.search_options() == {"M": 1000, "iterations": 200}
    assert get_profile("fast").search_options() == {}
    fast, balanced = get_profile("fast").dataset, get_profile("balanced").dataset
    assert balanced == DatasetConfig()  # balanced is the default
    assert fast.designs * fast.tiles == balanced.designs * balanced.tiles // 2  # half the rendering
    with pytest.raises(MetaSimError, match="unknown profile"):
        get_profile("turbo")


def test_table_and_plot(tmp_path):
    result = _result()
    table = format_tradeoff_table(result)
    assert table.count("\n| ") == len(result["points"])  # one row per point below the header
    assert "| search | adjoint M=1000, 200 it | 0.85 |" in table and "1.0e-07" in table
    assert accuracy(result["points"][1]["metrics"]) == pytest.approx(0.85)
    assert table.count("| - |") == len(result["points"])  # no unseen-design scores given
    result["points"][3]["metrics"].update(unseen_targets=83, unseen_flat_top1=0.9, unseen_sloped_top1=0.55)
    assert "| 0.90 / 0.55 (83) |" in format_tradeoff_table(result)
    path = plot_tradeoff(result, tmp_path / "plot.png")
    image = read_rgb8(path)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 20  # points, text and grid, not a blank canvas
    json.dumps(result)


def test_stage_times_come_from_the_measured_parts(tmp_path):
    from meta_sim.experiments.bench import stage_times

    render = tmp_path / "render.json"
    render.write_text(json.dumps({"presets": {"fast": {"seconds_per_tile": 0.1}}}))
    result = {"dataset": {"designs": 300, "tiles": 4, "preset": "fast"}, "feature_seconds_per_group": 0.2,
              "train_seconds": {"train_nams": 120.0},
              "splits": {"test": {"experiments": {"e1": {"nams_exhaustive": {"seconds_per_target": 0.05}}}},
                         "validation": {"experiments": {"e1": {"nams_exhaustive": {"seconds_per_target": 9.0}}}}}}
    stages = dict((name.split(":")[0].split(" (")[0], seconds) for name, seconds, _ in stage_times(result, render))
    assert stages["simulation"] == pytest.approx(120.0)  # 1,200 tiles x 0.1 s
    assert stages["training NAMS"] == 120.0
    assert stages["inference per target group of 9 tiles"] == pytest.approx(0.25)
    assert stages["inference per 5,000-image domain"] == pytest.approx(0.25 * 5000 / 9)
    assert "learning the roof segmenter" not in stages
    stages = dict((name, seconds) for name, seconds, _ in
                  stage_times({**result, "roof_segmenter_seconds": 300.0}, render))
    assert stages["learning the roof segmenter"] == 300.0
    assert stage_times(result, tmp_path / "missing.json") == []
    assert stage_times({k: v for k, v in result.items() if k != "train_seconds"}, render) == []  # a quick run


def test_search_points_come_from_the_nams_benchmarks_validation_rows(tmp_path):
    from types import SimpleNamespace

    from meta_sim.experiments.tradeoff import _search_points

    bench = _nams_result()
    bench["splits"]["validation"]["experiments"]["e1"]["uniform"] = _nams_row(0.02, 0.0)
    path = tmp_path / "nams.json"
    path.write_text(json.dumps(bench))
    base = SimpleNamespace(per_seed=100, feature_seconds_per_tile=0.01, one_off=300.0)
    points = {p.setting: p for p in _search_points(path, base)}
    assert set(points) == {"exhaustive", "adjoint M=1000, 200 it", "adjoint M=64, 100 it", "adjoint M=16, 50 it"}
    assert points["exhaustive"].seconds_per_group == pytest.approx(0.002 + 0.09)
    assert points["adjoint M=1000, 200 it"].targets == 20 and points["exhaustive"].targets == 300
    assert points["adjoint M=1000, 200 it"].metrics["flat_top1"] == 0.95  # validation's, not test's 0.5
    bench["tiles_per_target"] = 4
    path.write_text(json.dumps(bench))
    with pytest.raises(MetaSimError, match="groups of 4 tiles"):
        _search_points(path, base)
    path.write_text(json.dumps(_nams_result(validation_targets_per_seed=20)))
    with pytest.raises(MetaSimError, match="run `make bench-nams` again"):
        _search_points(path, base)
    path.write_text(json.dumps({"targets": 100, "experiments": {}}))  # a bench-nams result from before the splits
    with pytest.raises(MetaSimError, match="no E1 validation rows"):
        _search_points(path, base)
    with pytest.raises(MetaSimError, match="bench-nams"):
        _search_points(tmp_path / "missing.json", base)


def test_torch_side_commands_take_their_thread_count_from_meta_sim_threads(tmp_path, monkeypatch):
    import torch
    from click.testing import CliRunner

    from meta_sim.cli import main

    before = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        monkeypatch.setenv("META_SIM_THREADS", "1")
        # Fails on its options after the thread count is set: nothing is rendered.
        result = CliRunner().invoke(main, ["dataset", "--profile", "fast", "--paper-scale", "--cache", str(tmp_path)])
        assert result.exit_code == 2 and torch.get_num_threads() == 1
        monkeypatch.setenv("META_SIM_THREADS", "many")
        result = CliRunner().invoke(main, ["dataset", "--cache", str(tmp_path)])
        assert result.exit_code == 2 and "META_SIM_THREADS" in result.output
    finally:
        torch.set_num_threads(before)


def _nams_row(top1, seconds, targets=300):
    metrics = {"flat_top1": top1, "flat_top10": 1.0, "sloped_top1": top1, "sloped_top10": 0.9}
    return {**metrics, "seconds_per_target": seconds, "targets": targets,
            "intervals": {k: [v - 0.05, min(1.0, v + 0.05)] for k, v in metrics.items()}}


def _nams_result(validation_targets_per_seed=100):
    from meta_sim.experiments.splits import get_split

    def split(name, paper_top1):
        rows = {"nams_exhaustive": _nams_row(0.9, 0.002),
                "nams_adjoint_M1000_it200": _nams_row(paper_top1, 30.0, 20),
                "nams_adjoint_M64_it100": _nams_row(paper_top1 - 0.04, 1.0, 20),
                "nams_adjoint_M16_it50": _nams_row(paper_top1 - 0.3, 0.1, 20)}
        return {"settings": {e: get_split(e, name).to_dict() for e in ("e1", "e2")},
                "experiments": {"e1": rows, "e2": dict(rows)}}

    return {"dataset": {"designs": 600, "tiles": 2, "preset": "fast"}, "architecture": "additive",
            "train_seconds_other_architectures": {}, "roof_finder": "segmenter", "roof_weight_power": 4.0,
            "targets_per_seed": validation_targets_per_seed, "adjoint_targets": 20, "tiles_per_target": 9,
            "feature_seconds_per_group": 0.2,
            "splits": {"validation": split("validation", 0.95), "test": split("test", 0.5)}}


def test_the_fastest_adjoint_setting_is_chosen_on_validation_rows_and_the_table_puts_test_first():
    from meta_sim.experiments.bench import fastest_adjoint, format_nams_table

    result = _nams_result()
    sweep = ((1000, 200), (64, 100), (16, 50))
    assert fastest_adjoint(result["splits"]["validation"]["experiments"]["e1"], sweep) == {"M": 64, "iterations": 100}
    result["fastest_adjoint_keeping_e1"] = {"M": 64, "iterations": 100}
    table = format_nams_table(result)
    rows = [line for line in table.splitlines() if line.startswith("| E1 | nams_exhaustive |")]
    assert [r.split(" | ")[2] for r in rows] == ["test", "validation"]  # test first, validation beside it
    assert "| 0.900 [0.850, 0.950] |" in rows[0]
    assert "E2 seeds 21, 22, 23 with heldout-v2" in table and "E2 seeds 1, 2, 7 with heldout-v1" in table
    assert "on the validation split: M=64, 100 iterations" in table
    assert "stage (E4)" not in table  # no training timed: no stage times
