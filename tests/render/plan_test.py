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

