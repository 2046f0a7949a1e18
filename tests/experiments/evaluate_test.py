"""E1/E2 scoring: ranks by the HSV similarity, ties shared fairly."""

import pytest
import torch

from meta_sim.experiments.evaluate import (
    rankings,
    score,
    store_target_features,
    stored_target_features,
    target_features_path,
)
from meta_sim.experiments.ranking import Ranking
from meta_sim.sim.textures import ensure_default_bank, ensure_heldout_bank


def test_credit_counts_the_n_nearest_and_shares_ties_at_the_edge():
    ranking = Ranking(("a", "b", "c", "d", "e"), (0.9, 0.5, 0.2, 0.2, 0.2))
    assert ranking.credit("a", 1) == 1.0 and ranking.credit("b", 1) == 0.0
    assert ranking.credit("b", 2) == 1.0
    # Third place is shared by c, d and e: each gets one third of it.
    assert [ranking.credit(t, 3) for t in "cde"] == pytest.approx([1 / 3] * 3)
    assert ranking.credit("d", 4) == pytest.approx(2 / 3)
    assert ranking.credit("e", 10) == 1.0  # fewer candidates than n
    assert ranking.credit("unknown", 10) == 0.0
    # Expected credit of a uniform guess is n / candidates, whatever the ties.
    assert sum(ranking.credit(t, 3) for t in ranking.ids) == pytest.approx(3.0)


def test_e1_truth_is_its_own_nearest_texture_and_e2_ties_are_fair():
    bank, heldout = ensure_default_bank(), ensure_heldout_bank()
    e1 = rankings("e1", bank, heldout)
    for kind in ("flat", "sloped"):
        for truth, ranking in e1[kind].items():
            assert ranking.ids[0] == truth and ranking.credit(truth, 1) == 1.0
    e2 = rankings("e2", bank, heldout)
    for kind, n_bank in (("flat", 40), ("sloped", 44)):
        assert set(e2[kind]) == set(heldout.ids(kind))
        for ranking in e2[kind].values():
            assert len(ranking.ids) == n_bank
            assert list(ranking.similarity) == sorted(ranking.similarity, reverse=True)
            assert sum(ranking.credit(t, 10) for t in ranking.ids) == pytest.approx(10.0)
    truth = {"flat_roof": bank.ids("flat")[0], "sloped_roof": bank.ids("sloped")[0]}
    assert score(truth, truth, e1) == {"flat_top1": 1.0, "flat_top10": 1.0, "flat_closeness": 1.0,
                                       "sloped_top1": 1.0, "sloped_top10": 1.0, "sloped_closeness": 1.0}
    # Closeness: the pick's similarity as a share of the nearest bank texture's, in [0, 1], falling with the
    # place; 1 for every pick when nothing in the bank resembles the truth at all.
    for ranking in e2["flat"].values():
        shares = [ranking.closeness(t) for t in ranking.ids]
        assert shares[0] == 1.0 and shares == sorted(shares, reverse=True) and min(shares) >= 0.0
    assert next(iter(e2["flat"].values())).closeness("sloped-no-such") == 0.0
    from meta_sim.experiments.ranking import Ranking

    assert Ranking(("a", "b"), (0.0, 0.0)).closeness("b") == 1.0
    assert Ranking(("a", "b", "c"), (0.4, 0.1, 0.0)).closeness("b") == pytest.approx(0.25)


def test_e1_targets_are_not_the_training_sets_designs():
    # Training sets and E1 targets both default to seed 1; they once shared a random stream, so the
    # E1 targets were the training set's first designs and E1 measured recall of seen designs.
    from meta_sim.experiments.evaluate import target_jobs
    from meta_sim.render.jobs import sample_designs
    from meta_sim.sim.design import DesignSpace

    space = DesignSpace.load()
    train = sample_designs(space, 300, 1)
    targets = [job.design for job in target_jobs("e1", space, ensure_heldout_bank(), 100, 1)]
    # 300 of 1,760 designs: about 17 of 100 uniform targets are in the training set by chance.
    assert sum(t in train for t in targets) < 30
    assert targets[:10] != train[:10]
    assert len({job.city_seed for job in target_jobs("e1", space, ensure_heldout_bank(), 100, 1)}) == 100


def test_e1_scores_the_targets_the_training_set_lacks_apart():
    from types import SimpleNamespace

    from meta_sim.experiments.evaluate import score_method
    from meta_sim.render.jobs import Job

    bank = ensure_default_bank()
    flat, sloped = bank.ids("flat"), bank.ids("sloped")
    seen = {"flat_roof": flat[0], "sloped_roof": sloped[0]}
    unseen = {"flat_roof": flat[1], "sloped_roof": sloped[1]}
    wrong = {"flat_roof": flat[2], "sloped_roof": sloped[2]}
    ctx = SimpleNamespace(experiment="e1", jobs=[Job(seen, 1, "a"), Job(unseen, 2, "b")],
                          ranks=rankings("e1", bank, ensure_heldout_bank()), training_designs=[seen],
                          nams=SimpleNamespace(space=None))
    metrics, _ = score_method(ctx, lambda: [seen, wrong])  # recalls the seen design, misses the other
    assert metrics["flat_top1"] == metrics["sloped_top1"] == 0.5
    assert metrics["unseen_targets"] == 1
    assert metrics["unseen"]["flat_top1"] == metrics["unseen"]["sloped_top1"] == 0.0
    ctx.training_designs = []  # E2: no such split
    assert "unseen" not in score_method(ctx, lambda: [seen, wrong])[0]


def test_appearance_parameters_are_scored_and_e2_draws_them_as_e1_does():
    from meta_sim.experiments.evaluate import discrete, results_markdown, target_jobs
    from meta_sim.sim.design import DesignSpace

    bank, heldout = ensure_default_bank(), ensure_heldout_bank()
    base = DesignSpace.load()
    space = DesignSpace.from_dict({**base.to_dict(), "name": "look", "parameters": [
        *base.to_dict()["parameters"],
        {"name": "ground", "type": "categorical", "appearance": "ground", "choices": ["plain", "arid"]},
        {"name": "greenness", "type": "continuous", "appearance": "greenness", "low": 0.0, "high": 1.0}]})
    assert discrete(base) and not discrete(space)
    truth = {"flat_roof": bank.ids("flat")[0], "sloped_roof": bank.ids("sloped")[0], "ground": "arid",
             "greenness": 0.2}
    guess = {**truth, "ground": "plain", "greenness": 0.7}
    scores = score(guess, truth, rankings("e1", bank, heldout), space)
    assert scores["ground_hit"] == 0.0 and scores["greenness_error"] == pytest.approx(0.5)
    assert scores["flat_top1"] == 1.0
    e2 = [job.design for job in target_jobs("e2", space, heldout, 40, 1)]
    assert all(d["flat_roof"] in heldout.ids("flat") and d["sloped_roof"] in heldout.ids("sloped") for d in e2)
    assert {d["ground"] for d in e2} == {"plain", "arid"} and len({d["greenness"] for d in e2}) == 40
    assert list(e2[0]) == list(space.names)
    table = results_markdown({"experiment": "e1", "targets": 1, "tiles_per_target": 9, "methods": {
        "nams_adjoint": {**scores, "seconds_per_target": 0.01}}})
    assert "ground hit" in table and "greenness error" in table and "| 0.000 | 0.500 |" in table


def test_appearance_table_lists_every_metric_with_the_nams_interval():
    from meta_sim.experiments.bench import format_appearance_table

    scores = {"flat_top1": 0.9, "flat_top10": 1.0, "ground_hit": 0.8, "greenness_error": 0.12,
              "seconds_per_target": 0.02}
    result = {"targets": 100, "tiles_per_target": 9, "seed": 11, "adjoint": {"M": 64, "iterations": 100},
              "training": {"designs": 1200, "tiles": 2, "seconds": {"train_nams": 60.0, "train_dr": 30.0}},
              "methods": {"uniform": {**scores, "ground_hit": 0.25, "greenness_error": 0.33},
                          "dr": scores, "nams_adjoint": scores},
              "nams_intervals": {k: [v - 0.05, v + 0.05] for k, v in scores.items()}}
    table = format_appearance_table(result)
    assert "| ground hit | 0.250 | 0.800 | 0.800 | [0.750, 0.850] |" in table
    assert "| greenness error | 0.330 | 0.120 | 0.120 | [0.070, 0.170] |" in table
    assert "flat top1" in table and "seconds" not in table.split("\n")[3] and "1.5 min" in table
    assert table.startswith("E1 in `overhead-v1` (100 target groups")
    result["training"]["seconds"] = {"render": 1.0}
    assert "from the cache" in format_appearance_table(result)
    result["space"] = {"name": "overhead-towns-v3"}  # --space: the table names the space it measured
    assert format_appearance_table(result).startswith("E1 in `overhead-towns-v3` (100 target groups")


def test_bootstrap_intervals_hold_the_mean_and_narrow_with_more_groups():
    import numpy as np

    from meta_sim.experiments.evaluate import bootstrap_intervals

    rng = np.random.default_rng(3)
    few = [{"hit": float(h), "error": e} for h, e in zip(rng.random(20) < 0.7, rng.random(20))]
    many = [{"hit": float(h), "error": e} for h, e in zip(rng.random(400) < 0.7, rng.random(400))]
    for rows in (few, many):
        intervals = bootstrap_intervals(rows)
        for key, (low, high) in intervals.items():
            assert low < np.mean([r[key] for r in rows]) < high
    assert np.diff(bootstrap_intervals(many)["hit"]) < 0.5 * np.diff(bootstrap_intervals(few)["hit"])
    assert bootstrap_intervals([{"hit": 1.0}] * 5) == {"hit": [1.0, 1.0]}


def test_e2_intervals_resample_the_held_out_textures_not_the_groups():
    """Two textures, one always hit and one always missed, 50 groups each: resampling the groups says the
    rate is 0.5 give or take 0.1; resampling the textures says it could be anything from 0 to 1, which is what
    another draw of two textures would show. The other kind's metric keeps its own clusters; E1 has none."""
    import numpy as np

    from meta_sim.experiments.evaluate import bootstrap_intervals, texture_clusters

    designs = [{"flat_roof": "flat-a" if i < 50 else "flat-b", "sloped_roof": f"sloped-{i % 25}"} for i in range(100)]
    rows = [{"flat_top10": float(i < 50), "sloped_top10": float(i % 25 % 2)} for i in range(100)]
    clusters = texture_clusters("e2", designs)
    assert clusters["flat"][:2] == ["flat-a", "flat-a"] and len(clusters["sloped"]) == 100
    assert texture_clusters("e1", designs) is None
    groups, textures = bootstrap_intervals(rows), bootstrap_intervals(rows, clusters=clusters)
    assert 0.35 < groups["flat_top10"][0] < 0.5 < groups["flat_top10"][1] < 0.65
    assert textures["flat_top10"] == [0.0, 1.0]
    width = {name: np.diff(result["sloped_top10"])[0] for name, result in (("groups", groups), ("textures", textures))}
    assert width["textures"] > 1.7 * width["groups"]  # 25 textures, every other one hit
    with pytest.raises(ValueError, match="3 flat cluster labels for 100 rows"):
        bootstrap_intervals(rows, clusters={"flat": ["a", "b", "c"]})


def test_tables_give_the_sbi_baselines_training_time():
    from meta_sim.experiments.bench import format_nams_table
    from meta_sim.experiments.evaluate import results_markdown

    row = {"flat_top1": 0.5, "flat_top10": 0.9, "sloped_top1": 0.4, "sloped_top10": 0.8, "seconds_per_target": 0.01}
    table = results_markdown({"experiment": "e1", "targets": 2, "tiles_per_target": 9, "methods": {
        "dr": row, "sbi_nre": {**row, "train_seconds": 12.34}}})
    assert "| sbi_nre | 0.500 | 0.900 | 0.400 | 0.800 | 0.0100 |" in table
    assert "Training (when the cached model was trained): sbi_nre 12.3 s." in table
    assert "Training" not in results_markdown({"experiment": "e2", "targets": 2, "tiles_per_target": 9,
                                               "methods": {"dr": row}})
    from meta_sim.experiments.splits import get_split

    rows = {"e1": {"nams_exhaustive": {**row, "targets": 2}, "sbi_nre": {**row, "targets": 2}}}
    result = {"splits": {name: {"settings": {e: get_split(e, name).to_dict() for e in ("e1", "e2")},
                                "experiments": rows} for name in ("test", "validation")},
              "targets_per_seed": 2, "adjoint_targets": 1, "tiles_per_target": 9, "architecture": "additive",
              "train_seconds_other_architectures": {},
              "dataset": {"designs": 600, "tiles": 2, "preset": "fast"}, "feature_seconds_per_group": 0.2,
              "fastest_adjoint_keeping_e1": {"M": 250, "iterations": 200},
              "train_seconds": {"train_nams": 221.0, "train_dr": 52.0, "train_sbi_nre": 30.4}}
    table = format_nams_table(result)
    assert "Training: NAMS 221 s, DR 52 s, sbi_nre 30 s" in table and "| E1 | sbi_nre | validation |" in table
    # The closeness column: a row measured with it shows it, one measured before it a dash.
    rows["e1"]["sbi_nre"].update(flat_closeness=0.75, sloped_closeness=0.5)
    table = format_nams_table(result).splitlines()
    column = table[0].split(" | ").index("closeness flat / sloped")
    def cell(prefix):
        return next(line for line in table if line.startswith(prefix)).split(" | ")[column]

    assert cell("| E1 | sbi_nre | test |") == "0.750 / 0.500" and cell("| E1 | nams_exhaustive | test |") == "-"


def test_kept_target_features_are_read_back_only_for_the_same_extractor_and_targets(tmp_path):
    folders = [tmp_path / "e1-seed21" / f"g{i}" for i in range(3)]
    features = torch.arange(3 * 2 * 4, dtype=torch.float32).reshape(3, 2, 4)
    store_target_features(tmp_path, "colour+finder-abc", 8, folders, 2, features, 1.5)
    back = stored_target_features(tmp_path, "colour+finder-abc", 8, folders, 2)
    assert torch.equal(back["features"], features) and back["seconds"] == 1.5
    assert stored_target_features(tmp_path, "colour+finder-def", 8, folders, 2) is None  # a retrained finder
    assert stored_target_features(tmp_path, "colour+finder-abc", 8, folders[:2], 2) is None  # other targets
    assert stored_target_features(tmp_path, "colour+finder-abc", 8, folders, 1) is None  # fewer tiles per group
    assert stored_target_features(tmp_path, "colour+finder-abc", 1, folders, 2) is None  # other views
    path = target_features_path(tmp_path, "colour+finder-abc", 8, folders, 2)
    path.write_bytes(b"not a torch file")  # torn or tampered: featurised again, never trusted
    assert stored_target_features(tmp_path, "colour+finder-abc", 8, folders, 2) is None
    torch.save({"extractor": "colour+finder-abc", "features": features[:2], "seconds": 1.5}, path)
    assert stored_target_features(tmp_path, "colour+finder-abc", 8, folders, 2) is None  # wrong count
    nan = features.clone()
    nan[0, 0, 0] = float("nan")
    torch.save({"extractor": "colour+finder-abc", "features": nan, "seconds": 1.5}, path)
    assert stored_target_features(tmp_path, "colour+finder-abc", 8, folders, 2) is None  # not finite


def test_target_features_read_a_few_groups_at_a_time_are_those_of_reading_them_all(tmp_path, monkeypatch):
    """A split's tiles are read a few groups at a time (all at once, 2,700 tiles filled the memory of a 24 GB
    machine over a bench's splits); the features, batches and order are the same as reading them all."""
    from types import SimpleNamespace

    import numpy as np

    from meta_sim.experiments import evaluate
    from meta_sim.experiments.evaluate import _target_tile_features, group_features
    from meta_sim.pipeline.features import ColourTexture
    from meta_sim.sim.imageio import read_image
    from meta_sim.sim.tiles import write_tile

    rng = np.random.default_rng(0)
    jobs = [SimpleNamespace(name=f"d{g}") for g in range(5)]
    folders = [tmp_path / f"seed{g % 2}" for g in range(5)]
    for job, folder in zip(jobs, folders):
        folder.mkdir(exist_ok=True)
        for t in range(3):
            rgb = rng.uniform(0.0, 1.0, (16, 16, 3)).astype(np.float32)
            write_tile(folder / f"{job.name}_t{t:02d}.exr", rgb, np.zeros((16, 16), np.uint32),
                       np.zeros((16, 16), np.uint32), {})
    extractor = ColourTexture()
    groups = [[read_image(folder / f"{job.name}_t{t:02d}.exr") for t in range(3)] for job, folder in zip(jobs, folders)]
    _, whole = group_features(groups, extractor, 8, "all at once")
    monkeypatch.setattr(evaluate, "TARGET_GROUPS_READ", 2)  # 3 reads: 2, 2 and 1 groups
    parts = _target_tile_features(jobs, folders, 3, extractor, 8, "in parts")
    assert parts.shape == (5, 3, extractor.dim) and torch.allclose(parts, torch.stack(whole), atol=1e-6)
    assert torch.allclose(_target_tile_features(jobs, folders, 2, extractor, 8, "two tiles"), parts[:, :2], atol=1e-6)
