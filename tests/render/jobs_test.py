"""Jobs without Blender: a single design's job name."""

import numpy as np

from meta_sim.core.names import is_safe_name
from meta_sim.render.jobs import single_job, tile_path
from meta_sim.sim.design import DesignSpace, builtin_spaces


def test_a_single_designs_tiles_have_safe_names_in_every_space():
    roofs = DesignSpace.load("rooftops-v1")
    design = roofs.parse("flat_roof=3,sloped_roof=7")
    assert single_job(roofs, design, 4).name == f"{design['flat_roof']}+{design['sloped_roof']}_s4"  # as before
    for name in builtin_spaces():
        space = DesignSpace.load(name)
        designs = space.sample(np.random.default_rng(9), 2)
        jobs = [single_job(space, d, 123456789) for d in designs]
        assert all(is_safe_name(tile_path(".", job, 99).name) for job in jobs), name
        assert jobs[0].name != jobs[1].name and single_job(space, designs[0], 123456789) == jobs[0]
