"""Progress in a log: plain lines now and then and one at the end, no carriage returns."""

import io

from meta_sim.core.progress import LineBar


def test_line_bar_prints_plain_lines_at_intervals_and_at_the_end():
    out = io.StringIO()
    with LineBar(10, "render", "tile", initial=2, every=0.0, stream=out) as bar:
        bar.update(3)
        bar.update(5)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert [line.split(" [")[0] for line in lines] == ["render: 50% 5/10 tile", "render: 100% 10/10 tile",
                                                       "render: 100% 10/10 tile"]


def test_line_bar_stays_quiet_between_intervals():
    out = io.StringIO()
    bar = LineBar(100, "features", every=3600.0, stream=out)
    for _ in range(100):
        bar.update()
    assert out.getvalue() == ""
    bar.close()
    bar.close()
    assert out.getvalue().splitlines()[0].startswith("features: 100% 100/100 it [")
