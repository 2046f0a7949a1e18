"""Helpers the tests share (a module, not fixtures: they are called with arguments)."""

import math

from meta_sim.sim.design import DesignSpace


def toy_space(*widths, continuous=False) -> DesignSpace:
    """Categorical parameters p0, p1, ... of the given widths, optionally a continuous "density"."""
    params = [{"name": f"p{i}", "type": "categorical", "choices": [f"p{i}c{j}" for j in range(w)]}
              for i, w in enumerate(widths)]
    if continuous:
        params.append({"name": "density", "type": "continuous", "low": 0.3, "high": 0.9})
    return DesignSpace.from_dict({"format": "meta-sim-design-space", "version": 1, "name": "toy",
                                  "parameters": params})


def distance_to_polygon(x, y, polygon) -> float:
    """0 inside the polygon (even-odd rule), else the distance from (x, y) to its boundary."""
    polygon = list(polygon)
    inside = False
    for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1]):
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    if inside:
        return 0.0
    best = math.inf
    for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1]):
        dx, dy = x1 - x0, y1 - y0
        t = min(1.0, max(0.0, ((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy)))
        best = min(best, math.hypot(x - x0 - t * dx, y - y0 - t * dy))
    return best


def job_pixels(manifest, tasks=None) -> dict:
    """The tiles of a farm job's tasks (all by default): (rgb, instance, roof_class) keyed by file name."""
    from meta_sim.sim import tiles

    out = {}
    for task in manifest.tasks if tasks is None else tasks:
        for name in task.outputs:
            tile = tiles.read_tile(manifest.out_dir / name)
            out[name] = (tile.rgb, tile.instance, tile.roof_class)
    return out


def assert_same_tiles(a: dict, b: dict) -> None:
    """Two ``job_pixels`` results hold the same tiles, pixel for pixel."""
    import numpy as np

    assert a.keys() == b.keys()
    for name in a:
        assert all(np.array_equal(x, y) for x, y in zip(a[name], b[name])), name
