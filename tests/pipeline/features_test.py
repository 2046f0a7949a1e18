import hashlib
import sys
import types

import numpy as np
import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.pipeline.features import (
    ColourTexture,
    features_for_groups,
    group_feature,
    make_extractor,
    time_extractor,
    views,
)
from meta_sim.sim import tiles
from meta_sim.sim.imageio import read_image


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """Many small torch ops on two threads crawl when other processes hold the CPUs (xdist, renders)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def extractor():
    return ColourTexture()


def _batch(*images):
    return torch.from_numpy(np.stack(images).astype(np.float32)).permute(0, 3, 1, 2)


def _scene(roof, seed):
    """Grey-green ground, a road, and one roof (a rectangle filled with ``roof``) covering a fifth of the tile."""
    size = roof.shape[0]
    rng = np.random.default_rng(seed)
    img = np.empty(roof.shape, np.float32)
    img[:] = (0.35, 0.4, 0.3)
    img += 0.03 * rng.standard_normal(img.shape).astype(np.float32)
    img[:, size * 3 // 4: size * 7 // 8] = 0.45
    box = (slice(size // 8, size // 2), slice(size // 8, size * 5 // 8))
    img[box] = roof[box]
    return np.clip(img, 0, 1)


def _roof(colour, texture, seed, size=192):
    rng = np.random.default_rng(seed)
    img = np.empty((size, size, 3), np.float32)
    img[:] = colour
    if texture == "gravel":  # per-pixel speckle in brightness
        img *= 1 + 0.25 * rng.standard_normal((size, size, 1)).astype(np.float32)
    elif texture == "membrane":  # nearly flat
        img += 0.004 * rng.standard_normal((size, size, 1)).astype(np.float32)
    elif texture == "seams":  # standing-seam metal: a bright rib every 3 px
        img[:, ::3] *= 1.35
        img += 0.004 * rng.standard_normal((size, size, 1)).astype(np.float32)
    return np.clip(img, 0, 1)


def test_shape_dim_and_determinism(extractor):
    x = torch.rand(3, 3, 64, 80, generator=torch.Generator().manual_seed(0))
    a, b = extractor(x), extractor(x.clone())
    assert a.shape == (3, extractor.dim) and a.dtype == torch.float32 and extractor.dim == 774
    assert torch.equal(a, b)
    assert torch.equal(extractor(x[1:2]), a[1:2])  # an image's features do not depend on its batch
    assert "colour-texture-v1" in extractor.id


def test_finite_on_extreme_inputs(extractor):
    rng = np.random.default_rng(1)
    images = [np.zeros((40, 40, 3)), np.ones((40, 40, 3)), np.full((40, 40, 3), 0.5), rng.random((40, 40, 3))]
    out = extractor(_batch(*images))
    assert torch.isfinite(out).all() and out.min() >= 0
    for shape in ((16, 16), (500, 333), (333, 500), (17, 95)):
        assert torch.isfinite(extractor(torch.rand(1, 3, *shape))).all()
    weird = torch.tensor([float("nan"), float("inf"), -float("inf"), 5.0]).repeat(1, 3, 16, 4)
    assert torch.isfinite(extractor(weird)).all()
    with pytest.raises(MetaSimError, match="16 px minimum"):
        extractor(torch.rand(1, 3, 15, 64))


def test_views_are_the_dihedral_group():
    x = torch.arange(2 * 3 * 4 * 5, dtype=torch.float32).reshape(2, 3, 4, 5)
    for n in (1, 2, 4, 8):
        assert len(views(x, n)) == n
    eight = views(x, 8)
    assert torch.equal(eight[0], x) and torch.equal(eight[1], x.flip(-1))
    assert [v.shape[-2:] for v in eight] == [(4, 5)] * 4 + [(5, 4)] * 4
    flat = [v.flatten().tolist() for v in eight]
    assert len({tuple(f) for f in flat}) == 8
    for n in (0, 3, 16):
        with pytest.raises(MetaSimError, match="views"):
            views(x, n)


def test_default_extractor_is_dihedral_invariant(extractor):
    x = torch.nn.functional.avg_pool2d(torch.rand(2, 3, 70, 52, generator=torch.Generator().manual_seed(2)), 3, 1)
    feats = [extractor(v) for v in views(x, 8)]
    assert max((f - feats[0]).abs().max().item() for f in feats) < 1e-4
    tiles_ = [t.permute(1, 2, 0).numpy() for t in x]
    explicit = torch.stack(feats).mean(dim=0).mean(dim=0)
    assert torch.allclose(group_feature(tiles_, extractor, n_views=8), explicit, atol=1e-5)


def test_texture_and_colour_separate(extractor):
    colour = (0.62, 0.58, 0.52)
    tiles_ = {(texture, seed): _scene(_roof(colour, texture, seed), seed)
              for texture in ("membrane", "gravel", "seams") for seed in (1, 2)}
    tiles_["blue", 1] = _scene(_roof((0.52, 0.58, 0.62), "membrane", 1), 1)
    feats = dict(zip(tiles_, extractor(_batch(*tiles_.values()))))
    # Against the spread between two random instances of one roof texture:
    noise = max((feats[t, 1] - feats[t, 2]).norm() for t in ("membrane", "gravel", "seams"))
    assert (feats["membrane", 1] - feats["gravel", 1]).norm() > 8 * noise
    assert (feats["membrane", 1] - feats["seams", 1]).norm() > 8 * noise
    assert (feats["gravel", 1] - feats["seams", 1]).norm() > 8 * noise
    assert (feats["membrane", 1] - feats["blue", 1]).norm() > 4 * noise  # a small hue shift of one roof


def _tiny_net(out_dim=7):
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.ReLU(), torch.nn.AdaptiveAvgPool2d(1),
                               torch.nn.Flatten(), torch.nn.Linear(4, out_dim))


def test_torchscript_backbone(tmp_path):
    path = tmp_path / "net.pt"
    torch.jit.save(torch.jit.script(_tiny_net()), str(path))
    backbone = make_extractor(f"torchscript:{path}", input_size=32)
    assert backbone.dim == 7 and hashlib.sha256(path.read_bytes()).hexdigest()[:12] in backbone.id
    assert not backbone.dihedral_invariant
    x = torch.rand(5, 3, 40, 24)
    out = backbone(x)
    assert out.shape == (5, 7) and torch.equal(out, backbone(x))
    tiles_ = [t.permute(1, 2, 0).numpy() for t in x]
    expected = torch.stack([backbone(v) for v in views(x, 8)]).mean(dim=(0, 1))
    assert torch.allclose(group_feature(tiles_, backbone, n_views=8), expected, atol=1e-5)


def test_exported_backbone(tmp_path):
    net = _tiny_net().eval()
    program = torch.export.export(net, (torch.rand(2, 3, 32, 32),),
                                  dynamic_shapes={"input": {0: torch.export.Dim("batch")}})
    path = tmp_path / "net.pt2"
    torch.export.save(program, str(path))
    backbone = make_extractor(f"export:{path}", input_size=32)
    x = torch.rand(3, 3, 48, 48)
    assert backbone.id.startswith("export-") and torch.allclose(backbone(x), backbone(x))
    with torch.no_grad():
        resized = torch.nn.functional.interpolate(x, size=(32, 32), mode="bilinear", antialias=True)
        mean, std = torch.tensor([0.485, 0.456, 0.406]), torch.tensor([0.229, 0.224, 0.225])
        assert torch.allclose(backbone(x), net((resized - mean.view(3, 1, 1)) / std.view(3, 1, 1)), atol=1e-5)
    with pytest.raises(MetaSimError, match="check --input-size"):
        make_extractor(f"export:{path}", input_size=40)  # exported for 32 x 32 inputs
    (tmp_path / "notes.pt2").write_text("not a model")
    with pytest.raises(MetaSimError, match="not a torch.export model"):
        make_extractor(f"export:{tmp_path / 'notes.pt2'}")


def test_torchvision_backbone(tmp_path, monkeypatch):
    if "torchvision" not in sys.modules:
        monkeypatch.setitem(sys.modules, "torchvision", None)  # as if absent: a clear error, not a crash
        with pytest.raises(MetaSimError, match="torchscript:FILE"):
            make_extractor("torchvision:resnet18", weights=tmp_path / "w.pt")

    def get_model(name, weights=None):
        if name != "tiny":
            raise ValueError(name)
        return _tiny_net(5)

    fake = types.SimpleNamespace(models=types.SimpleNamespace(get_model=get_model))
    monkeypatch.setitem(sys.modules, "torchvision", fake)
    weights = tmp_path / "tiny.pth"
    torch.save(_tiny_net(5).state_dict(), weights)
    backbone = make_extractor("torchvision:tiny", weights=weights, input_size=24)
    assert backbone.dim == 5 and backbone.id.startswith("torchvision-tiny-")
    with pytest.raises(MetaSimError, match="needs its weights"):
        make_extractor("torchvision:tiny")
    with pytest.raises(MetaSimError, match="no model"):
        make_extractor("torchvision:huge", weights=weights)
    torch.save({"nope": torch.zeros(1)}, tmp_path / "bad.pth")
    with pytest.raises(MetaSimError, match="not a state dict"):
        make_extractor("torchvision:tiny", weights=tmp_path / "bad.pth")


def test_bad_specs(tmp_path):
    (tmp_path / "notes.pt").write_text("not a model")
    torch.jit.save(torch.jit.script(_tiny_net()), str(tmp_path / "net.pt"))
    for spec, weights, match in [("resnet", None, "unknown feature extractor"),
                                 ("torchscript:", None, "unknown feature extractor"),
                                 (f"torchscript:{tmp_path / 'missing.pt'}", None, "not found"),
                                 (f"torchscript:{tmp_path / 'notes.pt'}", None, "not a TorchScript model"),
                                 (f"torchscript:{tmp_path / 'net.pt'}", tmp_path / "net.pt", "drop --weights"),
                                 ("colour-texture", tmp_path / "net.pt", "drop --weights")]:
        with pytest.raises(MetaSimError, match=match):
            make_extractor(spec, weights)
    fixed = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(3 * 32 * 32, 4))  # only takes 32 x 32
    torch.jit.save(torch.jit.script(fixed), str(tmp_path / "fixed.pt"))
    with pytest.raises(MetaSimError, match="fails on a .* check --input-size"):
        make_extractor(f"torchscript:{tmp_path / 'fixed.pt'}", input_size=24)
    with pytest.raises(MetaSimError, match="input size"):
        make_extractor(f"torchscript:{tmp_path / 'fixed.pt'}", input_size=8)
    assert isinstance(make_extractor(), ColourTexture)


def test_groups_from_exr_tiles(tmp_path, extractor):
    rng = np.random.default_rng(3)
    paths = []
    for k, size in enumerate((64, 64, 48)):
        meta = tiles.tile_metadata(design={"flat_roof": "a"}, space="s", city_seed=1, tile_index=k, origin_m=(0, 0),
                                   size_px=(size, size), pixel_size_m=0.3, preset="fast")
        zeros = np.zeros((size, size), np.uint32)
        paths.append(tmp_path / f"t{k}.exr")
        tiles.write_tile(paths[-1], (rng.random((size, size, 3)) ** 2).astype(np.float32), zeros, zeros, meta)
    groups = [[read_image(p) for p in paths[:2]], [read_image(p) for p in paths]]
    together = features_for_groups(groups, extractor, n_views=8, batch_size=2)
    assert together.shape == (2, extractor.dim) and torch.isfinite(together).all()
    for g, group in enumerate(groups):
        assert torch.allclose(together[g], group_feature(group, extractor), atol=1e-6)
    with pytest.raises(MetaSimError, match="no tiles"):
        features_for_groups([[]], extractor)


def test_time_extractor(extractor):
    seconds = time_extractor(extractor, tile_px=64, n=2, views=8, repeats=1)
    assert seconds > 0  # its speed is bench-nams' feature time per group
