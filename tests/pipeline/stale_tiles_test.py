"""A training set whose tiles are rendered again under the same key drops what was derived from the old tiles."""

from types import SimpleNamespace

import pytest

from meta_sim.pipeline import workflow
from meta_sim.pipeline.dataset import DatasetConfig
from meta_sim.pipeline.workflow import ModelSettings, drop_derived, tiles_generation


def test_drop_derived_deletes_features_and_finders_and_counts_a_generation(tmp_path):
    (tmp_path / "tiles").mkdir()
    (tmp_path / "tiles" / "d0000_t00.exr").write_bytes(b"tile")
    assert tiles_generation(tmp_path) == 0
    assert drop_derived(tmp_path) == 0  # nothing derived yet (a first render): no new generation
    assert not (tmp_path / workflow.GENERATION_FILE).exists()
    for name in ("features-abc.pt", "tile-features-abc.pt", "roof-segmenter-1234-seed0.pt"):
        (tmp_path / name).write_bytes(b"derived")
    assert drop_derived(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tiles", workflow.GENERATION_FILE]
    assert (tmp_path / "tiles" / "d0000_t00.exr").exists()
    (tmp_path / "features-def.pt").write_bytes(b"derived again")
    assert drop_derived(tmp_path) == 2 and tiles_generation(tmp_path) == 2
    (tmp_path / workflow.GENERATION_FILE).write_text("junk")
    assert tiles_generation(tmp_path) == 0


def test_the_models_key_takes_the_generation_and_keeps_older_keys_at_zero():
    dataset, settings = DatasetConfig(designs=16, tiles=1), ModelSettings()
    first = settings.key(dataset, "x")
    assert settings.key(dataset, "x", 0) == first
    assert len({first, settings.key(dataset, "x", 1), settings.key(dataset, "x", 2)}) == 3


@pytest.mark.parametrize("written", [0, 5])
def test_preparing_features_drops_derived_files_only_when_tiles_were_written(tmp_path, monkeypatch, written):
    stale = tmp_path / "features-old.pt"
    stale.write_bytes(b"derived from older tiles")
    monkeypatch.setattr(workflow, "render_training_set",
                        lambda folder, config, progress: ([], SimpleNamespace(written=written)))
    monkeypatch.setattr(workflow, "build_features", lambda *a, **k: "features")
    monkeypatch.setattr("meta_sim.pipeline.features.make_extractor", lambda *a, **k: object())
    prepared = workflow._prepare_features(tmp_path, DatasetConfig(designs=16, tiles=1),
                                          ModelSettings(roof_colour=False), None)
    assert prepared.features == "features" and prepared.tiles_rendered == written
    assert stale.exists() == (written == 0)
    assert tiles_generation(tmp_path) == (1 if written else 0)
