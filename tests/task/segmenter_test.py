"""The task model: it learns, is deterministic for a seed, mixes its sources as asked, scores right."""

import numpy as np
import pytest
import torch

from meta_sim.core.errors import MetaSimError
from meta_sim.task.data import Pool
from meta_sim.task.score import all_building, count, predict
from meta_sim.task.train import TrainSettings, parse_mix, train_segmenter
from meta_sim.task.unet import UNet, UNetConfig, load_encoder, load_segmenter, save_segmenter

SMALL = dict(steps=40, batch=4, crop=32, mix=(3, 1), width=8, depth=3, lr=5e-3, pixel_size_m=0.6)


def _pool(name, n=6, px=48, seed=0, roof=(0.8, 0.3, 0.2), ground=(0.3, 0.5, 0.25)):
    """Images of coloured rectangles (buildings) on a noisy ground."""
    rng = np.random.default_rng(seed)
    images, masks = [], []
    for _ in range(n):
        image = np.clip(np.array(ground) + 0.05 * rng.standard_normal((px, px, 3)), 0, 1).astype(np.float32)
        mask = np.zeros((px, px), bool)
        for _ in range(3):
            y, x, h, w = rng.integers(0, px - 12, 2).tolist() + rng.integers(6, 12, 2).tolist()
            mask[y:y + h, x:x + w] = True
        image[mask] = roof
        images.append(image)
        masks.append(mask)
    return Pool(name, images, masks, 0.6, [f"{name}{k}" for k in range(n)])


def test_training_is_deterministic_learns_and_round_trips(tmp_path):
    real = _pool("real")
    first = train_segmenter(real, None, TrainSettings(**SMALL, seed=3))
    second = train_segmenter(real, None, TrainSettings(**SMALL, seed=3))
    other = train_segmenter(real, None, TrainSettings(**SMALL, seed=4))
    for a, b in zip(first.model.state_dict().values(), second.model.state_dict().values()):
        assert torch.equal(a, b)
    assert any(not torch.equal(a, b) for a, b in zip(first.model.state_dict().values(),
                                                       other.model.state_dict().values()))
    test = _pool("test", seed=9)
    counts, called = count(first, test.images, test.masks)
    trivial = all_building(test.masks).iou()
    assert counts.iou() > trivial + 0.3  # an easy task, learnt well past "all building"
    assert called[0].shape == test.masks[0].shape and called[0].dtype == bool
    save_segmenter(tmp_path / "seg.pt", first)
    back = load_segmenter(tmp_path / "seg.pt")
    assert back.pixel_size_m == 0.6 and back.training["seed"] == 3 and back.training["real"]["images"] == 6
    assert np.array_equal(predict(back, test.images[0]), predict(first, test.images[0]))


def test_synthetic_crops_follow_the_mix_and_shape_what_is_learnt():
    """Real roofs are red; synthetic ones blue. A blue-roofed test set is segmented well only by a
    model that saw synthetic crops."""
    real, synthetic = _pool("real"), _pool("synthetic", seed=1, roof=(0.2, 0.3, 0.9))
    blue = _pool("blue", seed=5, roof=(0.2, 0.3, 0.9))
    alone = train_segmenter(real, None, TrainSettings(**SMALL))
    mixed = train_segmenter(real, synthetic, TrainSettings(**SMALL))
    assert mixed.training["crops"] == [3, 1] and alone.training["crops"] == [4, 0]
    assert count(mixed, blue.images, blue.masks)[0].iou() > count(alone, blue.images, blue.masks)[0].iou() + 0.1


def test_predict_in_windows_equals_one_pass(monkeypatch):
    segmenter = train_segmenter(_pool("real"), None, TrainSettings(**{**SMALL, "steps": 2}))
    image = np.random.default_rng(0).random((70, 90, 3)).astype(np.float32)
    whole = predict(segmenter, image)
    import meta_sim.task.score as score

    monkeypatch.setattr(score, "WINDOW", 32)
    monkeypatch.setattr(score, "MARGIN", 16)
    windowed = predict(segmenter, image)
    assert whole.shape == (70, 90)
    # away from the image border the margin covers the receptive field's reach that matters
    assert np.abs(whole - windowed)[16:-16, 16:-16].max() < 0.05


def test_counts_and_trivial_answer():
    masks = [np.array([[1, 1], [0, 0]], bool), np.array([[0, 0], [0, 1]], bool)]
    trivial = all_building(masks)
    assert trivial.iou() == pytest.approx(3 / 8) and trivial.metrics()["recall"] == 1.0
    assert trivial.iou(np.array([1, 1])) == pytest.approx(1 / 4)


def test_mix_and_settings_are_checked():
    assert parse_mix("6:1", 7) == (6, 1) and parse_mix("1:6", 7) == (1, 6)
    assert parse_mix("100:1", 7) == (6, 1)  # a synthetic share gets a crop
    for bad in ("6", "a:b", "-1:2", "0:0", "6:0", "0:1", "nan:1", "inf:1"):
        with pytest.raises(MetaSimError, match="--mix"):
            parse_mix(bad, 7)
    for bad in (dict(crop=30), dict(steps=0), dict(lr=0.0), dict(mix=(3, 3)), dict(width=2), dict(pixel_size_m=0)):
        with pytest.raises(MetaSimError):
            TrainSettings(**{**SMALL, **bad}).check()
    with pytest.raises(MetaSimError, match="real and/or synthetic"):
        train_segmenter(None, None, TrainSettings(**SMALL))
    with pytest.raises(MetaSimError, match="m per pixel"):
        train_segmenter(Pool("p", *[[np.zeros((8, 8, 3), np.float32)], [np.zeros((8, 8), bool)]], 0.3, ["x"]),
                        None, TrainSettings(**SMALL))


def test_encoder_plug_in_and_bad_checkpoints(tmp_path):
    trained = train_segmenter(_pool("real"), None, TrainSettings(**{**SMALL, "steps": 3}))
    save_segmenter(tmp_path / "seg.pt", trained)
    fresh = UNet(UNetConfig(8, 3))
    assert load_encoder(fresh, tmp_path / "seg.pt") > 0
    assert torch.equal(fresh.encoder[0][0].weight, trained.model.encoder[0][0].weight)
    with pytest.raises(MetaSimError, match="does not fit"):
        load_encoder(UNet(UNetConfig(16, 3)), tmp_path / "seg.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(MetaSimError, match="not a segmenter checkpoint"):
        load_segmenter(tmp_path / "junk.pt")
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(MetaSimError, match="not a segmenter checkpoint"):
        load_segmenter(tmp_path / "other.pt")
    with pytest.raises(MetaSimError, match="not a file"):
        load_segmenter(tmp_path / "missing.pt")


def test_real_versus_rendered_accuracy_is_high_for_unlike_images_and_chance_for_alike():
    from meta_sim.task.realness import RealnessSettings, realness_accuracy

    settings = RealnessSettings(steps=60, batch=8, crop=32, width=8, test_crops=64)
    red, blue = _pool("red", seed=1), _pool("blue", seed=2, ground=(0.2, 0.3, 0.7))
    red_test, blue_test = _pool("red", seed=3), _pool("blue", seed=4, ground=(0.2, 0.3, 0.7))
    assert realness_accuracy(red, blue, red_test, blue_test, settings) > 0.95
    alike = realness_accuracy(red, _pool("red2", seed=5), red_test, _pool("red2", seed=6), settings)
    assert 0.3 < alike < 0.7
    first = realness_accuracy(red, blue, red_test, blue_test, RealnessSettings(steps=5, crop=32, width=8))
    assert first == realness_accuracy(red, blue, red_test, blue_test, RealnessSettings(steps=5, crop=32, width=8))


def test_a_critic_scores_images_like_the_real_ones_higher_and_is_deterministic():
    """A critic trained on scenes of green ground ("real") against blue ground scores held-out green scenes and
    scenes of a ground near it above blue ones (``realness_scores``: mean logit over an image's crops); the same
    seed gives the same scores, and an image smaller than a crop is refused."""
    from meta_sim.task.realness import RealnessSettings, realness_scores, train_critic

    settings = RealnessSettings(steps=60, batch=8, crop=32, width=8)
    red, blue = _pool("red", seed=1), _pool("blue", seed=2, ground=(0.2, 0.3, 0.7))
    net = train_critic(red, blue, settings)
    held = [*_pool("red", n=2, seed=3).images, *_pool("near", n=2, seed=4, ground=(0.3, 0.45, 0.35)).images,
            *_pool("blue", n=2, seed=5, ground=(0.2, 0.3, 0.7)).images]
    scores = realness_scores(net, held, settings.crop)
    assert min(scores[:4]) > max(scores[4:])
    assert scores == realness_scores(train_critic(red, blue, settings), held, settings.crop)
    with pytest.raises(MetaSimError, match="holds no 32-pixel crop"):
        realness_scores(net, [np.zeros((16, 40, 3), np.float32)], settings.crop)


def test_scene_colour_augmentation_recolours_the_ground_apart_and_is_seeded():
    """"scene" changes the crops beyond "light" and, in most crops, the ground's colour apart from the buildings'
    (the difference of their mean colours), which "light" keeps within its gain; its halves: "ground" recolours
    the ground alone (the buildings' pixels stay as "light" leaves them), "camera" changes the crops more than
    "light" but keeps the hue of the ground against the buildings (the direction of that difference); the same
    for a seed; an unknown augmentation is refused."""
    pool = _pool("p", n=8, px=64)
    crops = {colour: pool.crops(64, 48, torch.Generator().manual_seed(1), colour=colour)
             for colour in (None, "light", "ground", "camera", "scene")}
    for colour in ("ground", "camera", "scene"):
        again = pool.crops(64, 48, torch.Generator().manual_seed(1), colour=colour)
        assert torch.equal(again.image, crops[colour].image) and torch.equal(crops[colour].mask, crops[None].mask)
    mask = crops[None].mask
    both = (mask.sum(dim=(1, 2, 3)) > 50) & ((1 - mask).sum(dim=(1, 2, 3)) > 50)

    def contrast(images):  # (N, 3) the ground's mean colour minus the buildings'
        ground, building = 1 - mask, mask
        return ((images * ground).sum(dim=(2, 3)) / ground.sum(dim=(2, 3)).clamp_min(1)
                - (images * building).sum(dim=(2, 3)) / building.sum(dim=(2, 3)).clamp_min(1))[both]

    base = contrast(crops[None].image)

    def moved(colour):
        return (contrast(crops[colour].image) - base).norm(dim=1) / base.norm(dim=1)

    assert (crops["light"].image - crops[None].image).abs().mean() < 0.1 < (
        crops["scene"].image - crops[None].image).abs().mean()
    assert moved("light").max() < 0.2 and (moved("scene") > 0.3).float().mean() > 0.5

    def turned(colour):  # the cosine between the ground-minus-buildings colours after and before
        return torch.nn.functional.cosine_similarity(contrast(crops[colour].image), base, dim=1)

    change = {colour: (crops[colour].image - crops[None].image).abs().mean() for colour in ("light", "camera", "scene")}
    assert change["light"] < change["camera"] < change["scene"]
    assert turned("camera").min() > 0.95 and (turned("scene") < 0.95).float().mean() > 0.25
    assert (turned("ground") < 0.95).float().mean() > 0.25
    assert torch.equal(crops["ground"].image * mask, crops["light"].image * mask)
    with pytest.raises(MetaSimError, match="colour augmentation"):
        pool.crops(4, 32, torch.Generator(), colour="heavy")
    with pytest.raises(MetaSimError, match="--colour-augment"):
        TrainSettings(**SMALL, colour="heavy").check()
    assert TrainSettings(**SMALL).id("a") != TrainSettings(**SMALL, colour="scene").id("a")


def test_scene_colour_augmentation_carries_to_another_ground_and_camera():
    """Trained on red roofs on green ground, scored on the same roofs on tan ground seen darker: the segmenter
    trained with "scene" finds them better than the one trained with "light"."""
    train = _pool("train", n=8, px=64)
    test = _pool("test", n=6, px=64, seed=7, ground=(0.55, 0.45, 0.3))
    test.images = [(0.7 * image).astype(np.float32) for image in test.images]
    settings = {**SMALL, "steps": 120, "mix": (0, 4)}
    light = train_segmenter(None, train, TrainSettings(**settings))
    scene = train_segmenter(None, train, TrainSettings(**settings, colour="scene"))
    assert count(scene, test.images, test.masks)[0].iou() > count(light, test.images, test.masks)[0].iou() + 0.1


def test_the_classifier_views_take_away_colour_and_fine_detail():
    """"grey" leaves one brightness per pixel, "blur" smooths fine detail away (a checkerboard's contrast falls
    below a tenth) and keeps a crop's mean; "full" is the crop itself. A classifier told red from blue crops by
    colour alone is near chance in the grey view; an unknown view is refused."""
    from meta_sim.task.realness import RealnessSettings, realness_accuracy, view

    crops = torch.rand(2, 3, 24, 24, generator=torch.Generator().manual_seed(0))
    assert torch.equal(view(crops, "full"), crops)
    grey = view(crops, "grey")
    assert torch.allclose(grey[:, 0], grey[:, 1]) and torch.allclose(grey[:, 0], crops.mean(1))
    checker = ((torch.arange(24)[:, None] + torch.arange(24)[None]) % 2).float().expand(1, 3, 24, 24)
    blurred = view(checker, "blur")
    assert float(blurred.std()) < 0.1 * float(checker.std())
    assert float(blurred.mean()) == pytest.approx(float(checker.mean()), abs=0.02)
    assert torch.allclose(view(checker, "grey+blur"), view(view(checker, "grey"), "blur"), atol=1e-6)
    with pytest.raises(MetaSimError, match="unknown classifier view"):
        view(crops, "sepia")
    settings = RealnessSettings(steps=60, batch=8, crop=32, width=8, test_crops=64)
    red, blue = _pool("red", seed=1, ground=(0.5, 0.2, 0.2)), _pool("blue", seed=2, ground=(0.2, 0.2, 0.5))
    red_test, blue_test = _pool("red", seed=3, ground=(0.5, 0.2, 0.2)), _pool("blue", seed=4, ground=(0.2, 0.2, 0.5))
    assert realness_accuracy(red, blue, red_test, blue_test, settings) > 0.95
    assert realness_accuracy(red, blue, red_test, blue_test, RealnessSettings(**{**settings.__dict__,
                                                                                 "view": "grey"})) < 0.75
    with pytest.raises(MetaSimError, match="unknown classifier view"):
        realness_accuracy(red, blue, red_test, blue_test, RealnessSettings(view="sepia"))
