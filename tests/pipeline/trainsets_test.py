"""Datasets for trainers: rendered tiles and real image/mask folders give the same keys, in DataLoader workers."""

from pathlib import Path

import numpy as np
import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.pipeline.trainsets import RealDataset, TileDataset, loader
from meta_sim.sim import tiles
from meta_sim.sim.imageio import linear_to_srgb

REALDATA = Path(__file__).resolve().parents[3] / "shared" / "realdata"
KEYS = {"image", "mask", "roof_class", "instance", "meta"}


def _tiles(folder, n=4, px=24):
    folder.mkdir()
    rng = np.random.default_rng(0)
    for k in range(n):
        instance = np.zeros((px, px), np.uint32)
        instance[4:12, 4:12] = k + 1
        roof = (instance > 0).astype(np.uint32) * (1 + k % 2)
        meta = tiles.tile_metadata(design={"flat_roof": f"f{k}"}, space="toy", city_seed=k, tile_index=0,
                                   origin_m=(0, 0), size_px=(px, px), pixel_size_m=0.3, preset="fast")
        tiles.write_tile(folder / f"d{k:05d}_t00.exr", rng.random((px, px, 3)).astype(np.float32), instance, roof,
                         meta)
    return folder


def test_tile_dataset_items_and_a_dataloader_with_workers(tmp_path):
    data = TileDataset(_tiles(tmp_path / "tiles"))
    item = data[1]
    assert set(item) == KEYS and item["image"].shape == (3, 24, 24) and item["image"].dtype == torch.float32
    assert item["mask"].dtype == torch.uint8 and int(item["mask"].sum()) == 64
    assert set(item["roof_class"].unique().tolist()) == {0, 2} and set(item["instance"].unique().tolist()) == {0, 2}
    assert item["meta"]["design"] == '{"flat_roof": "f1"}' and item["meta"]["city_seed"] == 1
    linear = TileDataset(tmp_path / "tiles", colour="linear")[1]["image"]
    assert torch.allclose(item["image"], torch.from_numpy(linear_to_srgb(linear.numpy())).float(), atol=1e-5)
    batches = list(loader(data, batch_size=2, num_workers=2))
    assert [b["image"].shape for b in batches] == [(2, 3, 24, 24)] * 2
    assert batches[1]["meta"]["city_seed"].tolist() == [2, 3]
    with pytest.raises(MetaSimError, match="colour"):
        TileDataset(tmp_path / "tiles", colour="hdr")
    with pytest.raises(MetaSimError, match="no rendered tiles"):
        TileDataset(tmp_path)


@pytest.mark.skipif(not (REALDATA / "banepa").is_dir(), reason="../shared/realdata is not beside the project")
def test_real_dataset_resamples_images_and_masks_to_the_working_pixel_size():
    data = RealDataset(REALDATA / "banepa" / "images", REALDATA / "banepa" / "masks", pixel_size_m=0.13)
    assert len(data) == 48
    item = data[0]
    assert set(item) == KEYS and item["image"].shape == (3, 222, 222) and item["mask"].shape == (222, 222)
    assert set(item["mask"].unique().tolist()) <= {0, 1} and 0 < float(item["mask"].float().mean()) < 1
    assert item["meta"]["labels"] == "mask" and int(item["roof_class"].abs().sum()) == 0
    batch = next(iter(loader(data, batch_size=4, num_workers=2)))
    assert batch["image"].shape == (4, 3, 222, 222)
    with pytest.raises(MetaSimError, match="pixel size is unknown"):
        RealDataset(REALDATA / "banepa" / "images", REALDATA / "banepa" / "masks")[0]


def test_a_training_set_in_a_space_from_a_file_is_named_by_what_the_file_declares(tmp_path):
    import json

    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.sim.design import DesignSpace

    path = tmp_path / "space.json"
    spec = DesignSpace.load("rooftops-v1").to_dict()
    path.write_text(json.dumps(spec))
    first = DatasetConfig(space=str(path)).key()
    assert first != DatasetConfig().key()
    path.write_text(json.dumps({**spec, "layout": {"style": "dense"}}))  # same file, other scenes
    assert DatasetConfig(space=str(path)).key() != first
    assert DatasetConfig(space="overhead-v1").key() != DatasetConfig().key()
    assert DatasetConfig().identity()["space"] == "rooftops-v1"  # built-in spaces keep their keys


def test_caches_of_the_richer_scene_key_on_its_version_and_plain_ones_do_not(monkeypatch):
    """A change to what styled or furnished cities show (layout.SCENE_VERSION) renames their training sets
    and invalidates their tiles; rooftops-v1's training sets and tiles keep their names."""
    from meta_sim.pipeline.dataset import DatasetConfig
    from meta_sim.render.jobs import Job, RenderSettings
    from meta_sim.sim import layout
    from meta_sim.sim.design import DesignSpace
    from meta_sim.sim.quality import get_preset

    rich, plain = DatasetConfig(space="overhead-v1"), DatasetConfig()
    keys = rich.key(), plain.key()
    assert rich.identity()["scene"] == layout.SCENE_VERSION and "scene" not in plain.identity()
    space = DesignSpace.load("overhead-v1")
    job = Job(space.sample(np.random.default_rng(0), 1)[0], 3, "d0")
    settings = RenderSettings(space, [], get_preset("fast"), Path("unused"))
    plain_settings = RenderSettings(DesignSpace.load("rooftops-v1"), [], get_preset("fast"), Path("unused"))
    plain_job = Job(plain_settings.space.sample(np.random.default_rng(0), 1)[0], 3, "d0")
    assert settings.header(job)["scene"] == layout.SCENE_VERSION
    assert "scene" not in plain_settings.header(plain_job)
    assert RenderSettings(plain_settings.space, [], get_preset("fast"), Path("unused"),
                          style="dense").header(plain_job)["scene"] == layout.SCENE_VERSION
    monkeypatch.setattr(layout, "SCENE_VERSION", layout.SCENE_VERSION + 1)
    assert rich.key() != keys[0] and plain.key() == keys[1]
    assert settings.header(job)["scene"] == layout.SCENE_VERSION


@pytest.mark.skipif(not (REALDATA / "banepa").is_dir(), reason="../shared/realdata is not beside the project")
def test_real_folders_at_different_pixel_sizes_are_each_resampled_by_their_own():
    from meta_sim.sim.pixelsize import ImageFolder

    # Banepa's drone chips at 0.13 m stated with the folder, Rio's SpaceNet chips by the global option (0.5 m)
    banepa = ImageFolder.parse(f"{REALDATA / 'banepa'}:0.13", "--real", fallback_m=0.5, fallback_flag="--real-gsd")
    rio = ImageFolder.parse(REALDATA / "rio", "--real", fallback_m=0.5, fallback_flag="--real-gsd")
    items = [RealDataset(f.path / "images", f.path / "masks", working_pixel_size_m=0.6, folder=f)[0]
             for f in (banepa, rio)]
    # 512 px x 0.13 / 0.6 and 406 x 438 px x 0.5 / 0.6
    assert [tuple(i["image"].shape) for i in items] == [(3, 111, 111), (3, 338, 365)]
    assert [(i["meta"]["own_pixel_size_m"], i["meta"]["own_pixel_size_source"]) for i in items] == [
        (0.13, "flag"), (0.5, "global option")]
