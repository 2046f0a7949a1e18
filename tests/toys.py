"""Helpers the torch-side tests share (a module, not fixtures: they are called with arguments)."""

from meta_sim.sim.design import DesignSpace


def toy_space(*widths, continuous=False) -> DesignSpace:
    """Categorical parameters p0, p1, ... of the given widths, optionally a continuous "density"."""
    params = [{"name": f"p{i}", "type": "categorical", "choices": [f"p{i}c{j}" for j in range(w)]}
              for i, w in enumerate(widths)]
    if continuous:
        params.append({"name": "density", "type": "continuous", "low": 0.3, "high": 0.9})
    return DesignSpace.from_dict({"format": "meta-sim-design-space", "version": 1, "name": "toy",
                                  "parameters": params})
