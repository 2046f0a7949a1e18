"""The speed/accuracy report: profiles, table and plot from a measured-shaped result."""

import json

import numpy as np
import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.tradeoff import accuracy, format_tradeoff_table, plot_tradeoff
from meta_sim.pipeline.dataset import DatasetConfig
from meta_sim.pipeline.profiles import PROFILES, get_profile
from meta_sim.sim.imageio import read_rgb8


def _metrics(top1):
    return {"flat_top1": top1, "flat_top10": 1.0, "sloped_top1": top1 - 0.1, "sloped_top10": 0.9}


def _point(knob, setting, top1, seconds, one_off, test=True):
    """A point measured on validation with ``top1`` and, with ``test``, on test with 0.2 less."""
    metrics, targets = {"validation": _metrics(top1)}, {"validation": 300}
    if test:
        metrics["test"], targets["test"] = _metrics(top1 - 0.2), 300
    return {"knob": knob, "setting": setting, "metrics": metrics, "seconds_per_group": seconds,
            "one_off_seconds": one_off, "targets": targets, "detail": {}}


def _result(points=None):
    from meta_sim.experiments.splits import get_split

    return {"experiment": "e1", "splits": {name: get_split("e1", name).to_dict() for name in ("validation", "test")},
            "reported": "test", "targets_per_seed": 100, "adjoint_targets": 20, "tiles_per_target_group_default": 9,
            "views": {"max_abs_difference_1_vs_8_views": 1e-7, "seconds_per_9_tiles_1_view": 0.1,
                      "seconds_per_9_tiles_8_views_if_not_invariant": 0.8},
            "points": points or [_point("tiles per target group", "1", 0.5, 0.01, 300),
                                 _point("tiles per target group", "9", 0.9, 0.09, 300),
                                 _point("search", "adjoint M=1000, 200 it", 0.85, 16.0, 300),
                                 _point("training set", "600 x 4", 0.95, 0.09, 700),
                                 _point("render preset", "balanced", 0.9, 0.09, 900),
                                 _point("profile", "fast", 0.9, 0.09, 300)]}


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


def test_the_table_gives_each_point_a_test_row_and_its_validation_row_beside_it():
    result = _result()
    result["points"][2] = _point("search", "adjoint M=1000, 200 it", 0.85, 16.0, 300, test=False)
    table = format_tradeoff_table(result)
    rows = [line for line in table.splitlines() if line.startswith("| ") and not line.startswith("| knob")]
    assert len(rows) == 2 * len(result["points"])
    assert [r.split(" | ")[2] for r in rows] == ["test", "validation"] * len(result["points"])
    assert rows[0].startswith("| tiles per target group | 1 | test | 0.30 | 1.00 | 0.20 | 0.90 | 0.010 | 5.0 | 300 |")
    assert rows[1].startswith("| tiles per target group | 1 | validation | 0.50 | 1.00 | 0.40 | 0.90 |")
    # A point without test figures says so instead of showing another split's.
    assert "| search | adjoint M=1000, 200 it | test | - | - | - | - | 16.000 | 5.0 | - | - |" in table
    assert "| search | adjoint M=1000, 200 it | validation | 0.85 |" in table
    assert "seeds 21, 22, 23" in table and "seeds 1, 2, 7" in table and "1.0e-07" in table
    assert "chosen on the validation rows only" in table
    assert all(r.endswith("| - |") for r in rows)  # no unseen-design scores given
    result["points"][3]["metrics"]["test"].update(unseen_targets=83, unseen_flat_top1=0.9, unseen_sloped_top1=0.55)
    assert "| training set | 600 x 4 | test | 0.75 | 1.00 | 0.65 | 0.90 | 0.090 | 11.7 | 300 | 0.90 / 0.55 (83) |" \
        in format_tradeoff_table(result)
    json.dumps(result)


def test_the_table_reads_results_from_before_the_test_split_and_the_plot_refuses_them(tmp_path):
    old = {"experiment": "e1", "targets": 100, "adjoint_targets": 20, "views": _result()["views"],
           "points": [{"knob": "training set", "setting": "600 x 2", "metrics": _metrics(0.9),
                       "seconds_per_group": 0.07, "one_off_seconds": 300.0, "targets": 100, "detail": {}}]}
    table = format_tradeoff_table(old)
    assert "| training set | 600 x 2 | seed 1 | 0.90 | 1.00 | 0.80 | 0.90 | 0.070 | 5.0 | 100 | - |" in table
    assert "before the splits" in table
    from meta_sim.experiments.splits import get_split

    table = format_tradeoff_table({**old, "split": get_split("e1", "validation").to_dict()})
    assert "| 600 x 2 | validation | 0.90 |" in table and "| test |" not in table
    assert "validation split alone (seeds 1, 2, 7)" in table
    with pytest.raises(MetaSimError, match="no test figures"):
        plot_tradeoff(old, tmp_path / "plot.png")
    assert not (tmp_path / "plot.png").exists()


def _crowded_result():
    """Many points close together and some on the very same spot (the default is a setting of every knob),
    on both panels, and one point without test figures."""
    points = [_point("tiles per target group", str(g), 0.9 + 0.002 * g, 0.05 + 0.002 * g, 300) for g in range(1, 10)]
    points += [_point("search", f"adjoint M={m}, {it} it", 0.9 + 0.001 * it / 50, 0.06 + 0.0001 * m, 300)
               for m in (16, 64, 250, 1000) for it in (50, 100, 200)]
    points += [_point("search", name, 0.9, 0.068, 300) for name in ("exhaustive", "dr", "ms2", "sbi_nre")]
    points += [_point("architecture", name, 0.91, 0.068, 300) for name in ("paper", "factorised")]
    points += [_point("roof finder", "colour", 0.9, 0.068, 300, test=False)]
    points += [_point("training set", f"{d} x {t}", 0.9 + 0.003 * t, 0.07, 300 + d // 10 + t)
               for d in (150, 300, 600, 1700) for t in (2, 4, 9)]
    points += [_point("render preset", p, 0.9, 0.07, 306) for p in ("fast", "balanced", "quality")]
    points += [_point("profile", name, 0.9, 0.068, 306) for name in ("fast", "balanced", "paper")]
    return _result(points)


def test_the_plot_shows_test_accuracy_and_no_two_labels_overlap(tmp_path):
    from matplotlib import pyplot as plt

    from meta_sim.experiments.tradeoff import LABEL_GID, tradeoff_figure

    result = _crowded_result()
    shown = [p for p in result["points"] if "test" in p["metrics"]]
    fig = tradeoff_figure(result)
    try:
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        labels = [t for axis in fig.axes for t in axis.texts if t.get_gid() == LABEL_GID]
        profiles = sum(p["knob"] == "profile" for p in shown)
        assert len(labels) == len(shown) + profiles  # every drawn point labelled, the profiles on both panels
        boxes = [t.get_window_extent(renderer) for t in labels]
        overlapping = [(labels[i].get_text(), labels[j].get_text()) for i in range(len(boxes))
                       for j in range(i + 1, len(boxes)) if boxes[i].overlaps(boxes[j])]
        assert overlapping == []
        legend = fig.legends[0].get_window_extent(renderer)
        assert not any(box.overlaps(legend) for box in boxes)
        # The points are at the test split's accuracy, which the axes and the title name.
        drawn = sorted(round(y, 6) for axis in fig.axes for c in axis.collections for y in c.get_offsets()[:, 1])
        expected = sorted(round(accuracy(p["metrics"]["test"]), 6) for p in shown
                          for _ in range(2 if p["knob"] == "profile" else 1))
        assert drawn == expected
        assert all("test" in axis.get_ylabel() for axis in fig.axes)
        assert "test split" in fig.get_suptitle() and "without test figures, not drawn: 1" in fig.get_suptitle()
    finally:
        plt.close(fig)
    path = plot_tradeoff(result, tmp_path / "plot.png")
    image = read_rgb8(path)
    assert image.shape[0] > 300 and image.shape[1] > 600
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 20  # points, text and grid, not a blank canvas


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


def test_search_points_come_from_the_nams_benchmarks_rows_split_for_split(tmp_path):
    from types import SimpleNamespace

    from meta_sim.experiments.tradeoff import _search_points, read_nams_rows

    bench = _nams_result()
    for split in bench["splits"].values():
        rows = split["experiments"]["e1"]
        rows.update(uniform=_nams_row(0.02, 0.0), dr=_nams_row(0.8, 0.001), nams_exhaustive_paper=_nams_row(0.7, 0.002),
                    nams_exhaustive_colour_roof_finder=_nams_row(0.85, 0.002))
    bench["splits"]["test"]["experiments"]["e1"]["nams_adjoint_M1000_it200"]["seconds_per_target"] = 50.0
    path = tmp_path / "nams.json"
    path.write_text(json.dumps(bench))
    base = SimpleNamespace(feature_seconds_per_tile=0.01, one_off=300.0)
    points = {(p.knob, p.setting): p for p in _search_points(read_nams_rows(path, 100), base)}
    assert set(points) == {("search", "exhaustive"), ("search", "adjoint M=1000, 200 it"),
                           ("search", "adjoint M=64, 100 it"), ("search", "adjoint M=16, 50 it"), ("search", "dr"),
                           ("architecture", "paper"), ("roof finder", "colour")}
    exhaustive, paper = points["search", "exhaustive"], points["search", "adjoint M=1000, 200 it"]
    assert exhaustive.seconds_per_group == pytest.approx(0.002 + 0.09)
    assert paper.seconds_per_group == pytest.approx((30.0 + 50.0) / 2 + 0.09)  # timed over both splits' groups
    assert paper.targets == {"validation": 20, "test": 20} and exhaustive.targets == {"validation": 300, "test": 300}
    assert paper.metrics["validation"]["flat_top1"] == 0.95 and paper.metrics["test"]["flat_top1"] == 0.5
    del bench["splits"]["test"]
    path.write_text(json.dumps(bench))
    points = _search_points(read_nams_rows(path, 100), base)
    assert all(set(p.metrics) == {"validation"} for p in points)  # test missing, not validation's copied
    bench = _nams_result()
    bench["tiles_per_target"] = 4
    path.write_text(json.dumps(bench))
    with pytest.raises(MetaSimError, match="groups of 4 tiles"):
        read_nams_rows(path, 100)
    path.write_text(json.dumps(_nams_result(validation_targets_per_seed=20)))
    with pytest.raises(MetaSimError, match="run `make bench-nams` again with as many --targets"):
        read_nams_rows(path, 100)
    bench = _nams_result()
    bench["splits"]["test"]["settings"]["e1"]["seeds"] = [1, 2, 7]
    path.write_text(json.dumps(bench))
    with pytest.raises(MetaSimError, match="test seeds"):
        read_nams_rows(path, 100)
    bench = _nams_result()
    del bench["splits"]["validation"]
    path.write_text(json.dumps(bench))
    with pytest.raises(MetaSimError, match="no E1 validation rows"):
        read_nams_rows(path, 100)
    path.write_text(json.dumps({"targets": 100, "experiments": {}}))  # a bench-nams result from before the splits
    with pytest.raises(MetaSimError, match="predates the validation and test splits"):
        read_nams_rows(path, 100)
    with pytest.raises(MetaSimError, match="bench-nams"):
        read_nams_rows(tmp_path / "missing.json", 100)
    with pytest.raises(MetaSimError, match="run `make bench-ablations` first"):
        read_nams_rows(tmp_path / "missing.json", 100, "bench-ablations")
    # bench-ablations's (and bench-adjoint's) rows say where they come from, and rows bench-nams has too are left
    # out.
    bench = _nams_result()
    path.write_text(json.dumps(bench))
    points = _search_points(read_nams_rows(path, 100, "bench-ablations"), base, "bench-ablations",
                            skip=("nams_exhaustive",))
    assert points and all(p.detail["from"].startswith("bench-ablations row ") for p in points)
    assert ("search", "exhaustive") not in {(p.knob, p.setting) for p in points}



def test_cheaper_training_rows_cost_their_own_training_and_are_plotted_against_the_one_off_cost(tmp_path):
    """bench-ablations's rows that train for less (fewer segmenter steps, fewer NAMS epochs) keep the default's
    render and feature costs, with NAMS's training and the segmenter's learning replaced by their own times."""
    from types import SimpleNamespace

    from meta_sim.experiments.tradeoff import ONE_OFF_KNOBS, _search_points, ablation_one_offs, read_nams_rows

    bench = _nams_result()
    for split in bench["splits"].values():
        split["experiments"]["e1"].update(nams_exhaustive_roof_finder_steps_1000=_nams_row(0.9, 0.002),
                                          nams_exhaustive_max_epochs_300=_nams_row(0.88, 0.002))
    bench.update(train_seconds={"paper": 500.0, "max_epochs_300": 120.0, "roof_finder_steps_1000": 390.0},
                 roof_segmenter_seconds={"default": 300.0, "roof_finder_steps_1000": 100.0})
    path = tmp_path / "ablations.json"
    path.write_text(json.dumps(bench))
    base = SimpleNamespace(feature_seconds_per_tile=0.01, one_off=1000.0, train_seconds=400.0, finder_seconds=300.0)
    one_offs = ablation_one_offs(path, base)
    assert one_offs == {"nams_exhaustive_max_epochs_300": pytest.approx(1000 - 400 + 120),
                        "nams_exhaustive_roof_finder_steps_1000": pytest.approx(1000 - 400 - 300 + 390 + 100)}
    points = {(p.knob, p.setting): p for p in _search_points(read_nams_rows(path, 100, "bench-ablations"), base,
                                                             "bench-ablations", ("nams_exhaustive",), one_offs)}
    assert points["training epochs", "300"].one_off_seconds == pytest.approx(720.0)
    assert points["roof finder steps", "1000"].one_off_seconds == pytest.approx(790.0)
    assert points["search", "adjoint M=64, 100 it"].one_off_seconds == 1000.0  # the others: the default's
    assert {"training epochs", "roof finder steps"} <= set(ONE_OFF_KNOBS)


@pytest.mark.slow
def test_a_tiny_experiment_measures_every_point_on_both_splits(tmp_path):
    """The measuring side on a tiny training set and 2 target groups per seed (renders; not a measurement)."""
    from meta_sim.experiments.tradeoff import SPLITS, _Experiment

    render = tmp_path / "render.json"
    render.write_text(json.dumps({"presets": {"fast": {"seconds_per_tile": 0.1}}}))
    dataset = DatasetConfig(designs=24, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    experiment = _Experiment(dataset, 8, 2, tmp_path / "cache", render)
    cities = {name: {job.city_seed for job in jobs} for name, (_, jobs, _) in experiment.targets.items()}
    assert set(cities) == {"validation", "test"} and not cities["validation"] & cities["test"]
    assert all(features.shape[:2] == (6, 9) for _, _, features in experiment.targets.values())
    one, paper = experiment.run("tiles per target group", "1", group_tiles=1), \
        experiment.run("profile", "paper", 9, "adjoint", {"M": 8, "iterations": 3}, targets=2)
    assert one.targets == {"validation": 6, "test": 6} and paper.targets == {"validation": 2, "test": 2}
    for point in (one, paper):
        assert set(point.metrics) == {s.name for s in SPLITS}
        assert all(0 <= m[k] <= 1 for m in point.metrics.values() for k in ("flat_top1", "sloped_top10"))
        assert point.seconds_per_group > 0 and point.one_off_seconds >= 24 * 0.1  # at least the rendering
        assert point.detail["weights"] == experiment.weights and point.detail["views"] == 8
    again = _Experiment(dataset, 8, 2, tmp_path / "cache", render)  # a rerun reads the kept features
    assert again.feature_seconds_per_tile == experiment.feature_seconds_per_tile
    assert all(torch.equal(again.targets[name][2], features) for name, (_, _, features) in experiment.targets.items())


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
    assert "E2 seeds 21, 22, 23 with heldout-v2" in table and "E2 seeds 1, 2, 7 with heldout-v5" in table
    assert "on the validation split: M=64, 100 iterations" in table
    assert "from resampling the groups (2,000 draws)" in table  # a result from before the texture intervals
    result["e2_intervals"] = "held-out textures"
    assert "or the held-out textures of the roof kind" in format_nams_table(result)
    assert "stage (E4)" not in table  # no training timed: no stage times


def _measured(point, weights, dataset=None, day="2026-12-04"):
    """``point`` as a run of this bench measures it: its model's weights and training set, and the day."""
    point["detail"] = {"dataset": dataset or {"designs": 600, "tiles": 2}, "views": 8, "weights": weights,
                       "measured_on": day}
    return point


def test_training_sets_are_parsed_from_the_option_and_malformed_ones_are_clear_errors():
    from meta_sim.experiments.tradeoff import TRAINING_SETS, parse_training_sets

    assert parse_training_sets(None) == TRAINING_SETS
    assert parse_training_sets("") == ()
    assert parse_training_sets("150x4, 1700x9,150x4") == ((150, 4), (1700, 9))
    for bad in ("600", "0x2", "600x0", "-5x2", "600x2x2", "ax2", "1e3x2"):
        with pytest.raises(MetaSimError, match="DESIGNSxTILES"):
            parse_training_sets(bad)


def test_a_part_of_the_study_is_merged_into_an_earlier_one_on_the_same_targets():
    from meta_sim.experiments.tradeoff import merge_results

    small = {"designs": 150, "tiles": 4}
    earlier = _result([_measured(_point("tiles per target group", "9", 0.9, 0.09, 300), "aaa"),
                       {**_point("search", "dr", 0.8, 0.07, 300), "detail": {"from": "bench-nams row dr"}},
                       _measured(_point("training set", "150 x 4", 0.6, 0.08, 100), "bbb", small, "2026-12-03"),
                       _measured(_point("training set", "600 x 2", 0.9, 0.08, 300), "aaa"),
                       _measured(_point("profile", "fast", 0.85, 0.08, 200), "ccc", {"designs": 300, "tiles": 2})])
    part = _result([_measured(_point("tiles per target group", "9", 0.9, 0.09, 300), "aaa", day="2026-12-05"),
                    {**_point("search", "exhaustive", 0.9, 0.07, 300), "detail": {"from": "bench-nams row x"}},
                    _measured(_point("render preset", "balanced", 0.95, 0.09, 900), "ddd",
                              {"designs": 600, "tiles": 2, "preset": "balanced"}, "2026-12-05"),
                    _measured(_point("training set", "1700 x 9", 0.97, 0.08, 2000), "eee",
                              {"designs": 1700, "tiles": 9}, "2026-12-05")])
    merged = merge_results(earlier, part)
    assert [(p["knob"], p["setting"]) for p in merged["points"]] == [
        ("tiles per target group", "9"), ("search", "exhaustive"), ("training set", "150 x 4"),
        ("training set", "600 x 2"), ("training set", "1700 x 9"), ("render preset", "balanced"), ("profile", "fast")]
    # The measured point is the new one; the other bench's old row is not kept (each run reads those again).
    assert merged["points"][0]["detail"]["measured_on"] == "2026-12-05"
    table = format_tradeoff_table(merged)
    assert "Measured in parts" in table and "2026-12-03, 2026-12-04, 2026-12-05" in table
    assert "Measured in parts" not in format_tradeoff_table(part)  # one day: one run
    # A training set trained again with other weights: not one model's table.
    other = _result([_measured(_point("tiles per target group", "1", 0.5, 0.01, 300), "zzz")])
    with pytest.raises(MetaSimError, match="other weights"):
        merge_results(earlier, other)
    # Other targets, or an earlier result from before measuring in parts or before the splits.
    with pytest.raises(MetaSimError, match="targets_per_seed"):
        merge_results(earlier, {**part, "targets_per_seed": 50})
    with pytest.raises(MetaSimError, match="predates measuring in parts"):
        merge_results(_result(), part)
    with pytest.raises(MetaSimError, match="predates the validation and test splits"):
        merge_results({k: v for k, v in earlier.items() if k != "splits"}, part)


def test_the_weights_id_names_the_learnt_weights_not_the_run():
    from meta_sim.experiments.tradeoff import weights_id

    def model(seed):
        torch.manual_seed(seed)
        return torch.nn.Sequential(torch.nn.Linear(4, 3), torch.nn.BatchNorm1d(3)).to(torch.bfloat16)

    assert weights_id(model(0)) == weights_id(model(0)) and len(weights_id(model(0))) == 12
    assert weights_id(model(0)) != weights_id(model(1))
    changed = model(0)
    with torch.no_grad():
        changed[0].weight[0, 0] += 0.5
    assert weights_id(changed) != weights_id(model(0))


def test_merging_into_an_unreadable_result_fails_before_any_measuring(tmp_path):
    from click.testing import CliRunner

    from meta_sim.cli import main

    out = tmp_path / "tradeoff.json"
    out.write_text("{not json")
    result = CliRunner().invoke(main, ["bench", "tradeoff", "--merge", "--no-docs", "--out", str(out),
                                       "--cache", str(tmp_path / "cache")])
    assert result.exit_code != 0 and "cannot read the earlier trade-off result" in result.output
    assert out.read_text() == "{not json" and not (tmp_path / "cache").exists()
    result = CliRunner().invoke(main, ["bench", "tradeoff", "--training-sets", "600", "--no-docs", "--out", str(out)])
    assert result.exit_code != 0 and "DESIGNSxTILES" in result.output


def test_the_readme_gets_each_profiles_measured_row_and_says_which_are_not_measured(tmp_path):
    from pathlib import Path

    from meta_sim.experiments.publish import publish_section
    from meta_sim.experiments.tradeoff import format_profiles_table

    table = format_profiles_table(_result())
    assert "| fast | 0.700 / 0.600 | 1.000 / 0.900 | 0.900 / 0.800 | 0.090 | 5.0 | 300 |" in table
    assert "| balanced | not measured yet |" in table and "| paper | not measured yet |" in table
    assert table.splitlines()[0].startswith("| profile | E1 top-1 flat / sloped, test |")
    readme = tmp_path / "README.md"
    readme.write_text("intro\n<!-- bench:profiles -->\nold\n<!-- /bench:profiles -->\nafter\n")
    publish_section(readme, "profiles", table)
    text = readme.read_text()
    assert "old" not in text and table in text and text.startswith("intro\n") and text.endswith("after\n")
    readme.write_text("no markers\n")
    with pytest.raises(MetaSimError, match="no section"):
        publish_section(readme, "profiles", table)
    assert readme.read_text() == "no markers\n"
    # The project's own README has the section bench-tradeoff fills.
    assert "<!-- bench:profiles -->" in (Path(__file__).parents[2] / "README.md").read_text()
