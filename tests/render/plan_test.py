"""Planning a render builds only the held-out texture sets its designs name."""

from meta_sim.render import plan as render_plan
from meta_sim.render.options import RENDER_OPTIONS


def _plan(tmp_path, monkeypatch, **options):
    asked = []

    def spy(ids=None, bars=None):
        asked.append(sorted(ids))
        return []

    monkeypatch.setattr(render_plan, "ensure_heldout_banks", spy)
    render_plan.plan({**{opt.dest: opt.default for opt in RENDER_OPTIONS}, "out": tmp_path / "out", **options})
    return asked


def test_a_render_of_bank_textures_asks_for_no_held_out_set(tmp_path, monkeypatch, bank):
    assert _plan(tmp_path, monkeypatch, random_designs=20) == [[]]
    assert _plan(tmp_path, monkeypatch, design="flat_roof=flat-deck-olive,sloped_roof=0") == [["flat-deck-olive"]]



def test_bad_input_fails_before_a_fresh_cache_builds_any_bank(tmp_path, monkeypatch):
    import pytest

    from meta_sim.core.errors import MetaSimError

    monkeypatch.setenv("META_SIM_CACHE", str(tmp_path / "cache"))
    options = {**{opt.dest: opt.default for opt in RENDER_OPTIONS}, "out": tmp_path / "out"}
    for bad in ({"design": "flat_roof=nope,sloped_roof=0"}, {"random_designs": 2, "style": "dense",
                                                            "space": "overhead-towns-v1"}):
        with pytest.raises(MetaSimError):
            render_plan.plan({**options, **bad})
    assert not (tmp_path / "cache").exists()
