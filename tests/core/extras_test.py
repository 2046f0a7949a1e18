"""A missing optional package is named with the extra that brings it, in one line."""

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.core.extras import EXTRAS, require


def test_require_names_the_extra_of_a_missing_package(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "matplotlib", None)  # as if it were not installed
    with pytest.raises(MetaSimError, match=r"^the plot needs the matplotlib package: pip install 'meta-sim\[bench\]'$"):
        require("matplotlib", "the plot")


def test_every_extra_is_declared_in_pyproject():
    import tomllib
    from pathlib import Path

    extras = tomllib.loads((Path(__file__).resolve().parents[2] / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    assert set(EXTRAS.values()) <= set(extras)
    assert set(extras["all"][0].split("[")[1].rstrip("]").split(",")) == set(EXTRAS.values())
