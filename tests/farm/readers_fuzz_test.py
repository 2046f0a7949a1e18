"""Readers of files from outside never crash: whatever JSON they are given, only MetaSimError escapes.

Hypothesis throws random JSON (and random changes to a valid file) at each reader: design spaces,
design presets, job manifests, texture-bank manifests and a photo folder's textures.json.
"""

import json
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from meta_sim.core.errors import MetaSimError
from meta_sim.farm.manifest import Manifest
from meta_sim.sim.design import DesignSpace
from meta_sim.sim.presets import DesignPreset
from meta_sim.sim.textures.bank import TextureBank

EXAMPLES = 300
SPACE = DesignSpace.load()
KEYS = st.sampled_from(["format", "version", "name", "kind", "type", "choices", "parameters", "design", "low",
                        "high", "texture_kind", "layout", "layout_field", "vote_shares", "source_images",
                        "tasks", "space", "n_tiles", "tile_px", "pixel_size_m", "out_dir", "textures", "id",
                        "path", "repeat_m", "sha256", "outputs", "tiles", "city_seed", "flat_roof"])
SCALARS = (st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats(allow_nan=True)
           | st.text(max_size=12) | st.sampled_from(["meta-sim-design-space", "meta-sim-design-preset",
                                                     "meta-sim-farm-job", "meta-sim-texture-bank", "group",
                                                     "categorical", "continuous", "../x", "/tmp/x", "flat"]))
JSON = st.recursive(SCALARS, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(KEYS | st.text(max_size=6),
                                                                                        inner, max_size=6),
                    max_leaves=30)
FUZZ = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _mutations(valid: dict):
    """A valid document with one value anywhere in it replaced by random JSON."""
    def paths(node, prefix=()):
        yield prefix
        if isinstance(node, dict):
            for key, value in node.items():
                yield from paths(value, prefix + (key,))
        elif isinstance(node, list):
            for index, value in enumerate(node[:3]):
                yield from paths(value, prefix + (index,))

    def replace(path, value):
        doc = json.loads(json.dumps(valid))
        if not path:
            return value
        node = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        return doc

    return st.builds(replace, st.sampled_from(list(paths(valid))), JSON)


def _only_our_error(read, data, use=lambda result: None):
    """``read(data)`` raises MetaSimError or gives something its consumers can ``use`` without error."""
    try:
        result = read(data)
    except MetaSimError:
        return
    use(result)


def _use_preset(preset):
    for name in preset.design:
        assert 0.0 <= preset.confidence(name) <= 1.0
    preset.target()
    json.dumps(preset.to_dict(), allow_nan=False)


def _use_space(space):
    import numpy as np

    designs = space.sample(np.random.default_rng(0), 3)
    assert all(space.encode(d).shape == (space.dim,) for d in designs)
    json.dumps(space.to_dict(), allow_nan=False)


def _valid_preset():
    return {"format": "meta-sim-design-preset", "version": 1, "kind": "group", "name": "a-000",
            "design_space": "rooftops-v1", "design": {"flat_roof": SPACE.parameters[0].choices[0],
                                                      "sloped_roof": SPACE.parameters[1].choices[0]},
            "vote_shares": {"flat_roof": {SPACE.parameters[0].choices[0]: 1.0}}, "search": {"loss": 0.1},
            "source_images": ["a.png"], "model_id": "abc"}


@FUZZ
@given(st.one_of(JSON, _mutations(SPACE.to_dict())))
def test_design_space_reader(data):
    _only_our_error(DesignSpace.from_dict, data, _use_space)


@FUZZ
@given(st.one_of(JSON, _mutations(_valid_preset())))
def test_design_preset_reader(data):
    _only_our_error(lambda d: DesignPreset.from_dict(d, SPACE), data, _use_preset)
    _only_our_error(DesignPreset.from_dict, data, _use_preset)


@FUZZ
@given(data=st.data())
def test_job_manifest_reader(tmp_path_factory, data):
    valid = {"format": "meta-sim-farm-job", "version": 1, "space": SPACE.to_dict(), "bank": None, "preset": "fast",
             "n_tiles": 2, "tile_px": 32, "pixel_size_m": 0.3, "out_dir": "job-tiles",
             "tasks": [{"name": "a", "design": {"flat_roof": "x"}, "city_seed": 1, "tiles": [0], "outputs": ["a"]}]}
    document = data.draw(st.one_of(JSON, _mutations(valid)))
    _only_our_error(lambda d: Manifest.from_dict(d, Path("/nonexistent")), document)


@FUZZ
@given(st.data())
def test_texture_bank_reader(bank, data):
    valid = json.loads((bank.root / "manifest.json").read_text())
    valid["textures"] = valid["textures"][:2]
    document = data.draw(st.one_of(JSON, _mutations(valid)))
    _only_our_error(lambda d: TextureBank.from_dict(d, bank.root), document,
                    lambda b: [b.by_id(i) for kind in ("flat", "sloped") for i in b.ids(kind)])


CHECKPOINT_FIELDS = ["model_config", "space", "feature_norm", "extractor_id", "extra", "history", "kind"]


@FUZZ
@given(field=st.sampled_from(CHECKPOINT_FIELDS), value=JSON)
def test_checkpoint_metadata_reader(tmp_path_factory, field, value):
    """A checkpoint whose metadata is wrong but whose checksum is right (made by hand or by a bug)."""
    import io

    import torch

    from meta_sim.nams import NAMSConfig, build_model, load_checkpoint, save_checkpoint
    from meta_sim.nams.checkpoint import _digest
    from meta_sim.nams.norm import FeatureNorm

    folder = tmp_path_factory.mktemp("ckpt")
    model = build_model("nams", NAMSConfig(design_dim=SPACE.dim, feature_dim=4, hidden=(8, 8)))
    norm = FeatureNorm.fit(torch.randn(20, 4, generator=torch.Generator().manual_seed(1)))
    save_checkpoint(folder / "good.pt", "nams", model, model.config, SPACE.to_dict(), norm, "x")
    payload = torch.load(folder / "good.pt", weights_only=True)
    payload[field] = value
    payload["digest"] = _digest({k: v for k, v in payload.items() if k != "digest"})
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    (folder / "bad.pt").write_bytes(buffer.getvalue())

    def use(ckpt):
        int(ckpt.extra.get("tile_px", 384)), float(ckpt.extra.get("pixel_size_m", 0.3))
        str(ckpt.extractor_id)

    _only_our_error(lambda path: load_checkpoint(path, "nams"), folder / "bad.pt", use)


@FUZZ
@given(st.one_of(JSON, st.dictionaries(st.sampled_from(["flat/a.png", "sloped/b.png", "c.png"]), JSON, max_size=3)))
def test_photo_folder_options_reader(tmp_path_factory, options):
    from meta_sim.sim.textures.bank import _read_folder_options

    folder = tmp_path_factory.mktemp("photos")
    (folder / "textures.json").write_text(json.dumps(options))
    images = {"flat/a.png": folder / "flat" / "a.png", "sloped/b.png": folder / "sloped" / "b.png"}
    _only_our_error(lambda _: _read_folder_options(folder, images), None)
