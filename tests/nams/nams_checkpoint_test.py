"""Checkpoint files: round trip through weights_only loading, and every way a file can be wrong."""

import hashlib
import io

import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.nams import DRConfig, FeatureNorm, NAMSConfig, build_model, load_checkpoint, model_id, save_checkpoint
from meta_sim.sim.design import DesignSpace

SPACE = DesignSpace.from_dict({
    "format": "meta-sim-design-space", "version": 1, "name": "toy",
    "parameters": [{"name": "a", "type": "categorical", "choices": ["a0", "a1", "a2"]},
                   {"name": "b", "type": "categorical", "choices": ["b0", "b1", "b2", "b3", "b4"]}]})


def _nams():
    torch.manual_seed(0)
    model = build_model("nams", NAMSConfig(design_dim=SPACE.dim, feature_dim=6, hidden=(16, 32))).eval()
    model.z_mean.fill_(0.5)
    model.z_std.fill_(2.0)
    return model


def _norm():
    return FeatureNorm.fit(torch.randn(40, 6, generator=torch.Generator().manual_seed(1)))


def _save(path, model=None, kind="nams", **kw):
    model = model or _nams()
    return save_checkpoint(path, kind, model, model.config, SPACE.to_dict(), _norm(), "colour-stats-v1",
                           **kw)


def test_round_trip_loads_with_weights_only(tmp_path):
    model = _nams()
    path = tmp_path / "sub" / "nams.pt"
    history = {"train_loss": [1.0, 0.5], "best_epoch": 2, "train_config": {"lr": 0.001}}
    mid = _save(path, model, extra={"designs": 1700, "note": None}, history=history)
    assert mid == hashlib.sha256(path.read_bytes()).hexdigest()[:12] == model_id(path)
    assert list(tmp_path.joinpath("sub").iterdir()) == [path]  # no temporary file left behind

    raw = torch.load(path, weights_only=True)
    assert raw["format_version"] == 2 and raw["kind"] == "nams" and raw["extractor_id"] == "colour-stats-v1"
    assert {"z_mean", "z_std", "feature_scale"} <= set(raw["state_dict"])
    assert set(raw) == {"format", "format_version", "kind", "model_config", "state_dict", "space",
                        "feature_norm", "extractor_id", "history", "extra", "digest"}

    ckpt = load_checkpoint(path, kind="nams")
    assert ckpt.model_id == mid and ckpt.space == SPACE and ckpt.history == history
    assert ckpt.extra == {"designs": 1700, "note": None}
    assert not ckpt.model.training
    designs = torch.eye(SPACE.dim)
    with torch.no_grad():
        torch.testing.assert_close(ckpt.model(designs).features, model(designs).features, rtol=0, atol=0)
    assert torch.equal(ckpt.model.z_std, model.z_std)
    assert torch.equal(ckpt.feature_norm.std, _norm().std)
    assert _save(tmp_path / "again.pt", model, extra={"designs": 1700, "note": None}, history=history) == mid


def test_dr_checkpoint_and_kind_mismatch(tmp_path):
    dr = build_model("dr", DRConfig(feature_dim=6, design_dim=SPACE.dim, hidden=(16,))).eval()
    path = tmp_path / "dr.pt"
    _save(path, dr, kind="dr")
    assert load_checkpoint(path).kind == "dr"
    with pytest.raises(MetaSimError, match="is a 'dr' checkpoint; this needs a 'nams'"):
        load_checkpoint(path, kind="nams")
    with pytest.raises(ValueError, match="does not match the model"):
        _save(tmp_path / "x.pt", dr, kind="nams")


def test_missing_garbage_and_truncated_files(tmp_path):
    with pytest.raises(MetaSimError, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a zip at all")
    with pytest.raises(MetaSimError, match="not a readable meta-sim checkpoint"):
        load_checkpoint(garbage)
    good = tmp_path / "good.pt"
    _save(good)
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes(good.read_bytes()[:-200])
    with pytest.raises(MetaSimError):
        load_checkpoint(truncated)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(MetaSimError, match="not a meta-sim checkpoint"):
        load_checkpoint(other)


def test_a_flipped_byte_in_the_weights_is_caught(tmp_path):
    path = tmp_path / "nams.pt"
    _save(path)
    data = bytearray(path.read_bytes())
    payload = torch.load(io.BytesIO(bytes(data)), weights_only=True)
    needle = payload["state_dict"]["predictor.0.weight"].numpy().tobytes()[:16]
    at = bytes(data).index(needle)
    data[at + 3] ^= 0x40
    path.write_bytes(bytes(data))
    with pytest.raises(MetaSimError, match="corrupt"):
        load_checkpoint(path)


def _rewrite(path, **changes):
    payload = torch.load(path, weights_only=True)
    payload.update(changes)
    torch.save(payload, path)


def test_wrong_format_version_and_edited_contents(tmp_path):
    path = tmp_path / "nams.pt"
    _save(path)
    _rewrite(path, format_version=1)
    with pytest.raises(MetaSimError, match="format version 1"):
        load_checkpoint(path)
    _save(path)
    _rewrite(path, extractor_id="someone-else")
    with pytest.raises(MetaSimError, match="checksum"):
        load_checkpoint(path)


def test_only_plain_values_go_into_a_checkpoint(tmp_path):
    with pytest.raises(TypeError, match="extra.when"):
        _save(tmp_path / "x.pt", extra={"when": object()})
    model = _nams()
    with pytest.raises(ValueError, match="not the config"):
        save_checkpoint(tmp_path / "x.pt", "nams", model, {**model.config.to_dict(), "z_dim": 3},
                        SPACE.to_dict(), _norm(), "x")
    assert not list(tmp_path.iterdir())
