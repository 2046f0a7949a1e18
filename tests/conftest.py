"""Shared fixtures: a private cache (texture banks) for the whole test session."""

import os
import shutil
import tempfile
from pathlib import Path

import pytest

# Banks are built once per session into a private cache, never the user's ~/.cache.
_CACHE = Path(tempfile.mkdtemp(prefix="meta-sim-test-cache-"))
os.environ["META_SIM_CACHE"] = str(_CACHE)


def pytest_sessionfinish(session, exitstatus):
    """The private cache (texture banks, about 10 MB) goes with the session instead of piling up in /tmp."""
    shutil.rmtree(_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def bank():
    from meta_sim.sim.textures import ensure_default_bank

    return ensure_default_bank()


@pytest.fixture(scope="session")
def heldout_bank():
    from meta_sim.sim.textures import ensure_heldout_bank

    return ensure_heldout_bank()


@pytest.fixture(scope="session")
def heldout_v2_bank():
    from meta_sim.sim.textures import ensure_heldout_bank

    return ensure_heldout_bank(name="heldout-v2")


@pytest.fixture(scope="session")
def heldout_v3_bank():
    from meta_sim.sim.textures import ensure_heldout_bank

    return ensure_heldout_bank(name="heldout-v3")


@pytest.fixture(scope="session")
def heldout_v4_bank():
    from meta_sim.sim.textures import ensure_heldout_bank

    return ensure_heldout_bank(name="heldout-v4")


@pytest.fixture(scope="session")
def heldout_v5_bank():
    from meta_sim.sim.textures import ensure_heldout_bank

    return ensure_heldout_bank(name="heldout-v5")
