"""The NAMS loop on real renders at a small scale: dataset -> train -> eval and infer through the CLI."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from meta_sim.cli import main as cli
from meta_sim.nams import load_checkpoint
from meta_sim.pipeline.roofcolour import checkpoint_extractor
from meta_sim.sim.presets import load_preset

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
# A training set small enough for the default test run: 16 designs x 1 tile of 96 px at 1.2 m/px.
TINY = ["--designs", 16, "--tiles", 1, "--cities", 2, "--hidden", "64,128", "--max-epochs", 40,
        "--tile-px", 96, "--gsd", 1.2]


def _cli(*args):
    return CliRunner().invoke(cli, [str(a) for a in args], catch_exceptions=False)


@pytest.fixture(scope="module")
def tiny_env(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="module")
def evaluated(tiny_env, tmp_path_factory):
    out = tmp_path_factory.mktemp("e1")
    result = _cli("eval", "e1", "--out", out, "--targets", 3, "-M", 16, "--iterations", 5, "-S", 4,
                  "--cache", tiny_env, *TINY)
    assert result.exit_code == 0, result.output
    return out, result


def test_eval_writes_results_sheet_and_checkpoint(evaluated):
    out, result = evaluated
    results = json.loads((out / "results.json").read_text())
    assert results["experiment"] == "e1" and results["targets"] == 3
    assert results["architecture"] == "additive"  # the default
    assert set(results["methods"]) == {"uniform", "dr", "ms2", "sbi_nre", "nams_adjoint", "nams_exhaustive"}
    assert results["methods"]["sbi_nre"]["train_seconds"] > 0
    assert "train_sbi_nre" in results["training"]["seconds"]  # trained by this run, cached for the next
    for metrics in results["methods"].values():
        scores = {f"{kind}_{m}" for kind in ("flat", "sloped") for m in ("top1", "top10", "closeness")}
        for key in scores:
            assert 0.0 <= metrics[key] <= 1.0
        assert metrics["flat_top1"] <= metrics["flat_top10"] and metrics["seconds_per_target"] >= 0
        assert metrics["flat_top1"] <= metrics["flat_closeness"]  # a top-1 hit has closeness 1
        assert 0 <= metrics["unseen_targets"] <= 3
        assert set(metrics["unseen"]) == (scores if metrics["unseen_targets"] else set())
    assert "| nams_adjoint |" in (out / "results.md").read_text()
    assert "| sbi_nre |" in (out / "results.md").read_text() and "Training (when" in (out / "results.md").read_text()
    assert (out / "sheet.png").stat().st_size > 1000
    assert (out / "nams.pt").is_file() and (out / "dr.pt").is_file()
    # The default features: the roof colours in the stretched cone and in the score's own cone.
    ckpt = load_checkpoint(out / "nams.pt", "nams")
    assert ckpt.feature_norm.hist_blocks == (488, 488, 220, 220) and checkpoint_extractor(ckpt).score_cone


def test_eval_reuses_its_cached_training_set_and_model(evaluated, tiny_env, tmp_path):
    out, _ = evaluated
    again = _cli("eval", "e1", "--out", tmp_path, "--targets", 3, "-M", 16, "--iterations", 5, "-S", 4,
                 "--cache", tiny_env, *TINY)
    assert again.exit_code == 0
    without = _cli("eval", "e1", "--out", tmp_path / "no-ms2", "--targets", 3, "-M", 16, "--iterations", 5,
                   "-S", 4, "--no-ms2", "--no-sbi", "--cache", tiny_env, *TINY)
    assert without.exit_code == 0
    assert not {"ms2", "sbi_nre"} & set(json.loads((tmp_path / "no-ms2" / "results.json").read_text())["methods"])
    assert "train_sbi_nre" not in json.loads((tmp_path / "results.json").read_text())["training"]["seconds"]
    assert (tmp_path / "nams.pt").read_bytes() == (out / "nams.pt").read_bytes()
    first = json.loads((out / "results.json").read_text())["methods"]
    second = json.loads((tmp_path / "results.json").read_text())["methods"]
    for method in first:  # same seed, same designs inferred
        assert {k: v for k, v in first[method].items() if k != "seconds_per_target"} == \
               {k: v for k, v in second[method].items() if k != "seconds_per_target"}


def test_eval_on_the_test_split_draws_every_seed_and_heldout_v2(evaluated, tiny_env, tmp_path):
    result = _cli("eval", "e2", "--out", tmp_path, "--split", "test", "--targets", 1, "--target-tiles", 2, "-M", 16,
                  "--iterations", 5, "-S", 4, "--no-ms2", "--cache", tiny_env, *TINY)
    assert result.exit_code == 0, result.output
    assert "test split's" in result.output and "[" in result.output  # intervals in the table
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["split"] == {"experiment": "e2", "name": "test", "seeds": [21, 22, 23], "heldout": "heldout-v2"}
    assert results["targets"] == 3
    from meta_sim.sim.textures import ensure_heldout_bank

    v2 = set(ensure_heldout_bank(name="heldout-v2").ids())
    assert all({t["truth"]["flat_roof"], t["truth"]["sloped_roof"]} <= v2 for t in results["targets_detail"])
    for metrics in results["methods"].values():
        for key, (low, high) in metrics["intervals"].items():
            assert low <= metrics[key] <= high


def test_bench_nams_reports_the_test_split_beside_validation(evaluated, tiny_env):
    from meta_sim.experiments.bench import bench_nams, format_nams_table
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.workflow import ModelSettings

    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    result = bench_nams(targets=1, adjoint_targets=2, root=tiny_env, dataset=dataset, settings=settings, tiles=2,
                        sweep=((16, 5), (4, 5)), time_training=False)
    assert list(result["splits"]) == ["validation", "test"]
    for split, seeds in (("validation", [1, 2, 7]), ("test", [21, 22, 23])):
        settings_of = result["splits"][split]["settings"]
        assert settings_of["e1"]["seeds"] == settings_of["e2"]["seeds"] == seeds
        assert settings_of["e2"]["heldout"] == ("heldout-v5" if split == "validation" else "heldout-v2")
        for rows in result["splits"][split]["experiments"].values():
            assert rows["nams_exhaustive"]["targets"] == 3 and rows["nams_adjoint_M16_it5"]["targets"] == 2
            assert set(rows["nams_exhaustive"]["intervals"]) == {
                f"{kind}_{m}" for kind in ("flat", "sloped") for m in ("top1", "top10", "closeness")}
    assert "fastest_adjoint_keeping_e1" not in result  # bench_adjoint's choice
    table = format_nams_table(result)
    assert "| E2 | nams_exhaustive | test |" in table and "| E2 | nams_exhaustive | validation |" in table
    assert "E2 seeds 21, 22, 23 with heldout-v2" in table
    assert "nams_exhaustive_paper" not in table  # the variants are bench_ablations's


def test_bench_adjoint_sweeps_the_settings_on_a_few_of_the_same_targets_and_chooses_on_validation(
        evaluated, tiny_env):
    from meta_sim.experiments.bench import bench_adjoint, format_adjoint_table
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.workflow import ModelSettings

    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    stages = []

    def bars(label, total):
        stages.append((label, total))
        return lambda n=1: None

    result = bench_adjoint(targets=1, adjoint_targets=2, root=tiny_env, dataset=dataset, settings=settings, tiles=2,
                           sweep=((16, 5), (4, 5)), bars=bars)
    # A progress bar per adjoint setting and split, named by its setting.
    assert [s for s in stages if s[0].startswith("adjoint")] == \
        [("adjoint M=16 x 5 steps, 2 groups", 5), ("adjoint M=4 x 5 steps, 2 groups", 5)] * 4
    assert list(result["splits"]) == ["validation", "test"] and result["sweep"] == [[16, 5], [4, 5]]
    for part in result["splits"].values():
        for rows in part["experiments"].values():
            assert set(rows) == {"nams_exhaustive", "nams_adjoint_M16_it5", "nams_adjoint_M4_it5"}
            assert all(row["targets"] == 2 for row in rows.values())
    assert result["fastest_adjoint_keeping_e1"]["M"] in (16, 4)
    table = format_adjoint_table(result)
    assert "| E2 | nams_adjoint_M4_it5 | test |" in table and "Fastest setting within 0.05" in table


def test_bench_ablations_scores_each_variant_beside_the_default_on_the_same_targets(evaluated, tiny_env,
                                                                                     monkeypatch):
    from meta_sim.experiments import bench
    from meta_sim.experiments.bench import ablation_settings, bench_ablations, format_ablations_table
    from meta_sim.experiments.tradeoff import _nams_knob
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.workflow import ModelSettings

    # The cheaper-training rows at this tiny model's scale (the default's: 1,000 segmenter steps, 300 epochs).
    monkeypatch.setattr(bench, "ABLATION_FINDER_STEPS", 30)
    monkeypatch.setattr(bench, "ABLATION_MAX_EPOCHS", 20)
    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    same, own = ablation_settings(settings)
    assert set(same) == {"paper", "factorised", "no_roof_colour", "no_score_cone", "max_epochs_20"}
    assert set(own) == {"colour_roof_finder", "roof_weight_power_1", "roof_finder_steps_30"}
    assert own["colour_roof_finder"].roof_finder == "colour" and own["roof_weight_power_1"].roof_weight_power == 1.0
    assert same["max_epochs_20"].train == {"max_epochs": 20} and own["roof_finder_steps_30"].roof_finder_steps == 30
    cheap = ModelSettings(train={"max_epochs": 20}, roof_finder_steps=30)  # no "cheaper" row that is not cheaper
    assert not {"max_epochs_20", "roof_finder_steps_30"} & set().union(*ablation_settings(cheap))
    result = bench_ablations(targets=1, root=tiny_env, dataset=dataset, settings=settings, tiles=2)
    assert list(result["splits"]) == ["validation", "test"]
    names = {"nams_exhaustive", *(f"nams_exhaustive_{name}" for name in (*same, *own))}
    assert set(result["train_seconds"]) == set(same) | set(own) and min(result["train_seconds"].values()) > 0
    for part in result["splits"].values():
        for rows in part["experiments"].values():
            assert set(rows) == names
            for row in rows.values():
                assert row["targets"] == 3 and 0.0 <= row["flat_top1"] <= row["flat_top10"] <= 1.0
    assert set(result["roof_segmenter_seconds"]) == {"default", "roof_finder_steps_30"}
    assert result["roof_segmenter_seconds"]["roof_finder_steps_30"] < result["roof_segmenter_seconds"]["default"]
    # Every variant row is a knob of the trade-off study.
    assert {_nams_knob(name)[0] for name in names} == {"search", "architecture", "roof colour", "roof finder",
                                                       "roof weight power", "roof finder steps", "training epochs"}
    table = format_ablations_table(result)
    assert "the roof segmenter learnt in 30 steps, not the default's 3,000" in table
    assert "NAMS trained for at most 20 epochs" in table and "the roof segmenter: default " in table
    assert "| E1 | nams_exhaustive_paper | test |" in table and "| E2 | nams_exhaustive | validation |" in table
    assert "`nams_exhaustive_no_score_cone`: without those in the score's own colour cone" in table


def test_training_times_are_those_this_run_measured_when_it_trained_every_model(evaluated, tiny_env):
    """bench_nams does not train its models twice: when the run trained them, their recorded times are reported."""
    from meta_sim.experiments.bench import _training_times
    from meta_sim.nams import load_checkpoint
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.roofcolour import roof_finder_seconds
    from meta_sim.pipeline.workflow import ModelSettings, dataset_dir, ensure_models

    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    models = ensure_models(dataset, settings, tiny_env)
    path = models.nams_path
    written = path.stat().st_mtime_ns
    times = _training_times(models, dataset, settings, tiny_env, since=0.0)  # every cache file is newer than 1970
    assert times["training_timed"] == "in this run"
    nams = load_checkpoint(path, "nams")
    assert times["train_seconds"]["train_nams"] == round(nams.extra["seconds"], 2)
    assert set(times["train_seconds"]) == {"train_nams", "train_dr", "train_sbi_nre"}
    seconds = roof_finder_seconds(dataset_dir(dataset, tiny_env))
    assert seconds is not None and times["roof_segmenter_seconds"] == round(seconds, 1) > 0
    assert path.stat().st_mtime_ns == written  # nothing was trained again
    assert roof_finder_seconds(tiny_env / "nowhere") is None


def test_a_run_stopped_between_the_models_keeps_the_one_it_trained(evaluated, tiny_env):
    """ensure_models trains again only the checkpoint that is missing; a model trained alone is the same."""
    import torch

    from meta_sim.nams import load_checkpoint
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.workflow import ModelSettings, ensure_models

    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    models = ensure_models(dataset, settings, tiny_env)
    before = load_checkpoint(models.dr_path, "dr").model.state_dict()
    written = models.nams_path.stat().st_mtime_ns
    models.dr_path.unlink()
    again = ensure_models(dataset, settings, tiny_env)
    assert set(again.seconds) >= {"train_dr"} and "train_nams" not in again.seconds
    assert models.nams_path.stat().st_mtime_ns == written  # NAMS was not trained again
    after = load_checkpoint(again.dr_path, "dr").model.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)


def _target_folder(tmp_path, tiny_env):
    folder = tmp_path / "targets"
    result = _cli("render", "--design", "flat_roof=3,sloped_roof=5", "--seed", 777, "--tiles", 4,
                  "--tile-px", 96, "--gsd", 1.2, "--out", folder)
    assert result.exit_code == 0, result.output
    (folder / "designs.json").unlink()
    return folder


def test_infer_writes_presets_population_and_report(evaluated, tiny_env, tmp_path):
    out, _ = evaluated
    folder = _target_folder(tmp_path, tiny_env)
    (folder / "empty.png").write_bytes(b"")
    (folder / "notes.txt").write_text("not an image")
    good = next(folder.glob("*.exr"))
    (folder / "truncated.exr").write_bytes(good.read_bytes()[:3000])
    result = _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / "inferred", "--group-size", 2)
    assert result.exit_code == 0, result.output
    assert "empty.png" in result.output and "truncated.exr" in result.output
    presets = sorted((tmp_path / "inferred" / "presets").glob("*.json"))
    assert len(presets) == 2  # 4 tiles in groups of 2
    for path in presets:
        preset = load_preset(path)
        assert preset.kind == "group" and len(preset.source_images) == 2
        assert set(preset.design) == {"flat_roof", "sloped_roof"}
        for _param, shares in preset.vote_shares.items():
            assert abs(sum(shares.values()) - 1.0) < 1e-6
        # How much roof the finder saw: the share of the group's pixels, for each roof kind.
        assert 0.0 <= preset.search["roof_pixels_flat"] <= 1.0 and 0.0 <= preset.search["roof_pixels_sloped"] <= 1.0
        assert preset.search["roof_pixels_flat"] + preset.search["roof_pixels_sloped"] > 0.0
        # Beside it, the range the model's training cities span but for 5% at either end.
        assert set(preset.roof_evidence()) == {"flat", "sloped"}
        assert all(0.0 <= e["range"][0] <= e["range"][1] <= 1.0 for e in preset.roof_evidence().values())
    population = load_preset(tmp_path / "inferred" / "population.json")
    assert population.kind == "population" and sum(d["count"] for d in population.designs) == 2
    report = json.loads((tmp_path / "inferred" / "report.json").read_text())
    assert report["group_count"] == 2 and len(report["groups"]) == 2 and len(report["skipped"]) == 3
    assert report["architecture"] == "additive"
    assert "(additive NAMS)" in (tmp_path / "inferred" / "report.md").read_text()
    assert set(report["groups"][0]["roof_pixels"]) == {"flat", "sloped"}
    # How the search compared the roof colours: the default (roofcolour.SEARCH_COLOUR), blurred, and a target far
    # from every design ranked by its roof colours (the roof match, SEARCH_MATCH: the space chooses roof materials);
    # which groups were searched so. A margin, when the default has one, keeps the first answer the match finds close.
    from meta_sim.pipeline.roofcolour import SEARCH_COLOUR, SEARCH_MATCH

    assert report["colour_comparison"] == {
        "exponent": SEARCH_COLOUR[0], "blurred": True, "blur_weight": SEARCH_COLOUR[2], "far_loss": SEARCH_MATCH[0],
        "far": {"match": {"kinds": 2, "params": ["flat_roof", "sloped_roof"], "swatch_weight": SEARCH_MATCH[1],
                          "swatches": [True, True], **({"unmix": SEARCH_MATCH[3]} if SEARCH_MATCH[3] else {}),
                          **({"render_share": SEARCH_MATCH[4]} if SEARCH_MATCH[4] else {})}},
        **({"far_margin": SEARCH_MATCH[2]} if SEARCH_MATCH[2] is not None else {})}
    assert report["groups_far_from_every_design"] == sum(g["far"] for g in report["groups"])
    assert ("(far):" in (tmp_path / "inferred" / "report.md").read_text()) == bool(
        report["groups_far_from_every_design"])
    assert all(isinstance(load_preset(tmp_path / "inferred" / "presets" / f"{g['name']}.json").search["far"], bool)
               for g in report["groups"])
    assert "| flat roof pixels |" in (tmp_path / "inferred" / "report.md").read_text()
    assert set(report["roof_pixels_range"]) == {"flat", "sloped"}
    assert set(report["groups_outside_roof_pixels_range"]) == {"flat", "sloped"}
    assert (tmp_path / "inferred" / "report.png").stat().st_size > 1000
    assert report["population_near"] == 0 and report["population_designs"] == len(population.designs)


def test_infer_population_near_renders_from_each_groups_best_ranked_designs(evaluated, tiny_env, tmp_path):
    """--population-near 3: population.json's designs are the groups' 3 best-ranked designs each (the group
    presets and the distribution are the answers, as without it); --population-near above -S is refused."""
    out, _ = evaluated
    folder = _target_folder(tmp_path, tiny_env)
    runs = {}
    for near in (0, 3):
        runs[near] = tmp_path / f"near{near}"
        result = _cli("infer", folder, "--model", out / "nams.pt", "--out", runs[near], "--group-size", 2,
                      "--population-near", near)
        assert result.exit_code == 0, result.output
    plain, near = (load_preset(runs[n] / "population.json") for n in (0, 3))
    assert sum(d["count"] for d in plain.designs) == 2 and sum(d["count"] for d in near.designs) == 6
    assert near.search == {"groups": 2, "near": 3} and near.distribution == plain.distribution
    assert {json.dumps(d["design"], sort_keys=True) for d in plain.designs} <= {
        json.dumps(d["design"], sort_keys=True) for d in near.designs}  # each group's answer ranks first
    assert sorted(p.read_text() for p in (runs[0] / "presets").glob("*.json")) == sorted(
        p.read_text() for p in (runs[3] / "presets").glob("*.json"))
    assert json.loads((runs[3] / "report.json").read_text())["population_near"] == 3
    assert f"samples {len(near.designs)} distinct designs: each group's 3 best-ranked designs" in (
        runs[3] / "report.md").read_text()
    assert f"samples {len(plain.designs)} distinct designs: the groups' designs." in (runs[0] / "report.md").read_text()
    refused = _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / "bad", "--population-near", 51)
    assert refused.exit_code != 0 and "--population-near must be between 0 and --keep/-S (50)" in refused.output
    assert not (tmp_path / "bad").exists()


def test_infer_warns_when_a_groups_roof_evidence_is_outside_the_training_cities(evaluated, tiny_env, tmp_path):
    """A model whose training cities all showed more flat roof than any target flags every group low, one
    whose training cities all showed less sloped roof flags them high, in the presets, the report and on
    stderr; one whose range holds everything flags none; the roof evidence itself is the same."""
    from meta_sim.nams import load_checkpoint, save_checkpoint

    out, _ = evaluated
    ckpt = load_checkpoint(out / "nams.pt", "nams")
    for name, flat, sloped in (("lenient", (0.0, 1.0), (0.0, 1.0)), ("strict", (1.0, 1.0), (0.0, 0.0))):
        extra = dict(ckpt.extra, roof_evidence={"quantile": 0.05, "flat": {"low": flat[0], "high": flat[1]},
                                                "sloped": {"low": sloped[0], "high": sloped[1]}})
        save_checkpoint(tmp_path / f"{name}.pt", "nams", ckpt.model, ckpt.model.config, ckpt.space.to_dict(),
                        ckpt.feature_norm, ckpt.extractor_id, extra=extra, history=ckpt.history)
    folder = _target_folder(tmp_path, tiny_env)
    runs = {}
    for name in ("lenient", "strict"):
        runs[name] = _cli("infer", folder, "--model", tmp_path / f"{name}.pt", "--out", tmp_path / name,
                          "--group-size", 2)
        assert runs[name].exit_code == 0, runs[name].output
    assert "warning: 2 of 2 groups have low flat-roof evidence" in runs["strict"].stderr
    assert "warning: 2 of 2 groups have high sloped-roof evidence" in runs["strict"].stderr
    assert "roof evidence" not in runs["lenient"].stderr
    report = json.loads((tmp_path / "strict" / "report.json").read_text())
    assert report["groups_outside_roof_pixels_range"] == {"flat": {"low": 2, "high": 0},
                                                          "sloped": {"low": 0, "high": 2}}
    assert all(g["roof_pixels_outside"] == {"flat": "low", "sloped": "high"} for g in report["groups"])
    assert "(low)" in (tmp_path / "strict" / "report.md").read_text()
    lenient = json.loads((tmp_path / "lenient" / "report.json").read_text())
    assert lenient["groups_outside_roof_pixels_range"] == {"flat": {"low": 0, "high": 0},
                                                           "sloped": {"low": 0, "high": 0}}
    assert [g["roof_pixels"] for g in lenient["groups"]] == [g["roof_pixels"] for g in report["groups"]]


def test_infer_is_deterministic(evaluated, tiny_env, tmp_path):
    out, _ = evaluated
    folder = _target_folder(tmp_path, tiny_env)
    for name in ("a", "b"):
        assert _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / name, "--search", "adjoint",
                    "-M", 32, "--iterations", 10, "-S", 8).exit_code == 0
    a = sorted((tmp_path / "a" / "presets").glob("*.json"))
    b = sorted((tmp_path / "b" / "presets").glob("*.json"))
    assert [p.read_text() for p in a] == [p.read_text() for p in b]


def test_infer_profile_sets_the_search_and_explicit_options_win(evaluated, tiny_env, tmp_path):
    out, _ = evaluated
    folder = _target_folder(tmp_path, tiny_env)
    result = _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / "paper", "--profile", "paper",
                  "-M", 16, "--iterations", 4, "-S", 4, "--group-size", 2)
    assert result.exit_code == 0, result.output
    # One progress bar over the images, read, featurised and searched as they stream past.
    assert re.search("target images: 100%.*4/4", result.stderr), result.stderr
    report = json.loads((tmp_path / "paper" / "report.json").read_text())
    assert report["method"] == "adjoint" and report["group_count"] == 2
    preset = load_preset(sorted((tmp_path / "paper" / "presets").glob("*.json"))[0])
    assert (preset.search["M"], preset.search["iterations"]) == (16, 4)
    result = _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / "fast", "--profile", "fast")
    assert result.exit_code == 0, result.output
    assert json.loads((tmp_path / "fast" / "report.json").read_text())["method"] == "exhaustive"


def test_dataset_profile_and_paper_scale_conflict(tmp_path):
    result = CliRunner().invoke(cli, ["dataset", "--profile", "balanced", "--paper-scale", "--cache", str(tmp_path)])
    assert result.exit_code == 2 and "not both" in result.output


@pytest.mark.parametrize("content", ["empty", "junk"])
def test_infer_without_usable_images_is_an_error(evaluated, tmp_path, content):
    out, _ = evaluated
    folder = tmp_path / "folder"
    folder.mkdir()
    if content == "junk":
        (folder / "a.png").write_bytes(b"\x89PNG not really")
    result = CliRunner().invoke(cli, ["infer", str(folder), "--model", str(out / "nams.pt"),
                                      "--out", str(tmp_path / "o")])
    assert result.exit_code == 2
    assert "no readable images" in result.output
    assert not (tmp_path / "o").exists()


def test_infer_rejects_a_damaged_checkpoint(evaluated, tiny_env, tmp_path):
    out, _ = evaluated
    folder = _target_folder(tmp_path, tiny_env)
    bad = tmp_path / "bad.pt"
    data = bytearray((out / "nams.pt").read_bytes())
    data[len(data) // 2] ^= 0xFF
    bad.write_bytes(bytes(data))
    result = CliRunner().invoke(cli, ["infer", str(folder), "--model", str(bad), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "corrupt" in result.output


def _kampala(tmp_path, n: int):
    """A folder of ``n`` real drone tiles of Kampala (0.3 m web-mercator z19), copied into the test's
    temporary folder only."""
    folder = tmp_path / "kampala"
    folder.mkdir()
    for path in sorted((REALDATA / "kampala" / "ramp-data" / "sample_2" / "input").glob("OAM-*-19.png"))[:n]:
        shutil.copy(path, folder / path.name)
    return folder


@pytest.mark.skipif(not (REALDATA / "kampala").is_dir(), reason="../shared/realdata is not beside the project")
def test_infer_on_real_aerial_imagery(evaluated, tmp_path):
    """Real drone tiles of Kampala (0.3 m web-mercator z19 tiles) through the whole infer path."""
    out, _ = evaluated
    folder = _kampala(tmp_path, 4)
    result = _cli("infer", folder, "--model", out / "nams.pt", "--out", tmp_path / "inferred", "--group-size", 4)
    assert result.exit_code == 0, result.output
    preset = load_preset(next((tmp_path / "inferred" / "presets").glob("*.json")))
    assert np.isfinite(preset.search["loss"])


def test_train_with_the_papers_architecture(evaluated, tiny_env, tmp_path):
    """Same cached training set; another architecture is another cached model, and says so."""
    from meta_sim.nams import load_checkpoint

    result = _cli("train", "--out", tmp_path, "--architecture", "paper", "--cache", tiny_env, *TINY)
    assert result.exit_code == 0, result.output
    assert "(paper NAMS)" in result.output and "render" in result.output
    paper = load_checkpoint(tmp_path / "nams.pt", "nams")
    assert paper.model.config.architecture == "paper" and paper.model.config.blocks == ()
    default = load_checkpoint(evaluated[0] / "nams.pt", "nams")
    assert default.model.config.architecture == "additive" and default.model.config.blocks == (40, 44)
    bad = CliRunner().invoke(cli, ["train", "--out", str(tmp_path), "--architecture", "deep"])
    assert bad.exit_code != 0 and "deep" in bad.output


def test_a_model_without_roof_colour_is_scored_on_the_defaults_features(evaluated, tiny_env, tmp_path):
    """bench-ablations' row nams_exhaustive_no_roof_colour: the default's targets, MS2 pool included, cut to
    the features the model without the roof-colour histograms was trained on."""
    from meta_sim.experiments.evaluate import EvalSettings, method_runs, prepare_eval, score_method, score_other_model
    from meta_sim.nams import load_checkpoint
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.pipeline.workflow import ModelSettings

    result = _cli("train", "--out", tmp_path, "--no-roof-colour", "--cache", tiny_env, *TINY)
    assert result.exit_code == 0, result.output
    plain = load_checkpoint(tmp_path / "nams.pt", "nams")
    dataset = DatasetConfig(designs=16, tiles=1, cities=2, tile_px=96, pixel_size_m=1.2)
    settings = ModelSettings(nams={"hidden": [64, 128]}, train={"max_epochs": 40})
    ctx = prepare_eval("e1", dataset, settings, EvalSettings(targets=3), tiny_env)
    assert ctx.pool is not None and plain.feature_norm.hist_dim == 0 < ctx.nams.feature_norm.hist_dim
    row = score_other_model(ctx, plain, seed=1)
    assert row["targets"] == 3 and 0.0 <= row["flat_top1"] <= row["flat_top10"] <= 1.0
    # The default model through the same function scores as its own exhaustive run.
    same = score_other_model(ctx, ctx.nams, seed=1)
    own, _ = score_method(ctx, method_runs(ctx, 1, {})["nams_exhaustive"])
    assert {k: same[k] for k in ("flat_top1", "sloped_top10")} == {k: own[k] for k in ("flat_top1", "sloped_top10")}
    # The neural-adjoint search of an evaluation shows its steps (minutes in a large space).
    opened, steps = [], []
    method_runs(ctx, 1, {"M": 4, "S": 2, "iterations": 3}, bars=lambda name, total: opened.append((name, total))
                or steps.append)["nams_adjoint"]()
    assert opened == [("search", 3)] and sum(steps) == 3


def test_a_stage_that_finds_everything_cached_shows_no_bar(capsys):
    from meta_sim.cli.base import _Bars

    bars = _Bars()
    bars("cached stage", 600)
    step = bars("working stage", 3)
    step(1)
    step(2)
    late = bars("last stage", 1)
    step(5)  # a closed stage's late steps are dropped, not drawn on a new bar
    late(1)
    bars.close()
    err = capsys.readouterr().err
    assert "cached stage" not in err
    assert "working stage" in err and "3/3" in err and "last stage" in err and "1/1" in err
    assert "5/3" not in err and "8/3" not in err


# The CLI with bpy unimportable, as in a base install (`pip install meta-sim`, no `render` extra).
_WITHOUT_BPY = "import sys; sys.modules['bpy'] = None; from meta_sim.cli import main; main()"


@pytest.mark.skipif(not (REALDATA / "kampala").is_dir(), reason="../shared/realdata is not beside the project")
def test_infer_runs_without_bpy(evaluated, tmp_path):
    out, _ = evaluated
    folder = _kampala(tmp_path, 2)
    done = subprocess.run([sys.executable, "-c", _WITHOUT_BPY, "infer", str(folder), "--model", str(out / "nams.pt"),
                           "--out", str(tmp_path / "inferred"), "--group-size", "2"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert load_preset(tmp_path / "inferred" / "population.json").kind == "population"


def test_render_without_bpy_names_the_extra_to_install(tmp_path):
    done = subprocess.run([sys.executable, "-c", _WITHOUT_BPY, "render", "--design", "flat_roof=1,sloped_roof=1",
                           "--tiles", "1", "--tile-px", "32", "--out", str(tmp_path / "out")],
                          capture_output=True, text=True)
    assert done.returncode == 2
    assert done.stderr.strip() == "error: rendering needs the bpy package: pip install 'meta-sim[render]'"
    assert not (tmp_path / "out").exists()  # nothing written


def test_two_processes_sharing_a_cache_prepare_a_training_set_once(tmp_path):
    """Both succeed; the tiles are rendered by one of them (the other waits on the entry's lock)."""
    args = [sys.executable, "-m", "meta_sim.cli", "dataset", "--designs", "6", "--tiles", "1", "--cities", "1",
            "--tile-px", "32", "--gsd", "3.6", "--no-roof-colour", "--views", "1", "--cache", str(tmp_path / "c")]
    runs = [subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    outputs = [run.communicate(timeout=600) for run in runs]
    assert [run.returncode for run in runs] == [0, 0], [err for _, err in outputs]
    rendered = sorted(int(re.search(r"\((\d+) rendered now\)", out)[1]) for out, _ in outputs)
    assert rendered == [0, 6]


def test_infer_reads_each_target_at_its_stated_pixel_size_and_records_it(evaluated, tmp_path):
    from meta_sim.sim.textures.pngio import write_png

    out, _ = evaluated  # a model of 96 px tiles at 1.2 m
    folder = tmp_path / "targets"
    folder.mkdir()
    rng = np.random.default_rng(5)
    for k in range(3):
        write_png(folder / f"p{k}.png", (rng.random((96, 96, 3)) * 255).astype(np.uint8))
    model = ["--model", str(out / "nams.pt"), "--group-size", "2"]

    def infer(target, name):
        result = CliRunner().invoke(cli, ["infer", target, *model, "--out", str(tmp_path / name)])
        report = json.loads((tmp_path / name / "report.json").read_text()) if result.exit_code == 0 else None
        return result, report

    assumed, report = infer(str(folder), "assumed")
    assert assumed.exit_code == 0, assumed.output
    assert [line for line in assumed.stderr.splitlines() if "pixel size" in line] == [
        f"warning: 3 of 3 images in {folder} do not state their pixel size; taken as the model's 1.2 m. State it: "
        f"{folder}:METRES, a pixel_size.txt in {folder} or --gsd"]
    assert report["pixel_sizes"] == {str(folder): [{"pixel_size_m": 1.2, "source": "assumed", "stated": False,
                                                    "images": 3}]}
    assert report["tiles"] == 3  # taken as the model's pixels: one tile per image
    assert f"Pixel size of {folder}: 1.2 m per pixel (assumed) for 3 images." in \
        (tmp_path / "assumed" / "report.md").read_text()

    (folder / "pixel_size.txt").write_text("2.4\n")
    from_file, report = infer(str(folder), "file")
    assert from_file.exit_code == 0 and "warning: 3 of 3" not in from_file.output
    assert report["tiles"] == 12  # 2.4 m pixels doubled to 1.2 m: 192 px, four tiles per image
    assert report["pixel_sizes"][str(folder)] == [{"pixel_size_m": 2.4, "source": "pixel_size.txt", "stated": True,
                                                   "images": 3}]
    flagged, report = infer(f"{folder}:2.5", "flag")
    assert flagged.exit_code == 0 and report["pixel_sizes"][str(folder)][0]["source"] == "flag"

    for target, message in ((f"{folder}:0.6", f"{folder}:0.6 says 0.6 m per pixel but {folder / 'pixel_size.txt'} "
                                              f"says 2.4; correct or remove {folder}:0.6 or"),
                            (f"{folder}:x", "the pixel size after ':' must be a number")):
        refused, _ = infer(target, "refused")
        assert refused.exit_code == 2 and message in refused.output and refused.output.count("\n") == 1
    (folder / "pixel_size.txt").write_text("2.4 m\n")
    refused, _ = infer(str(folder), "refused")
    assert refused.exit_code == 2 and "pixel_size.txt must hold one number" in refused.output
    assert not (tmp_path / "refused").exists()
