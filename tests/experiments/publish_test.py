"""A benchmark's JSON and its table in the docs come from one call."""

import json

import pytest

from meta_sim.core.errors import MetaSimError
from meta_sim.experiments.publish import publish


def test_publish_writes_the_json_and_replaces_only_its_own_table(tmp_path):
    docs = tmp_path / "benchmarks.md"
    docs.write_text("# Benchmarks\n\n<!-- bench:render -->\nold\n<!-- /bench:render -->\n\n"
                    "<!-- bench:farm -->\nfarm table\n<!-- /bench:farm -->\n")
    written = publish({"a": 1}, tmp_path / "render.json", "| new |\n", "render", docs)
    assert written == [tmp_path / "render.json", docs]
    assert json.loads((tmp_path / "render.json").read_text()) == {"a": 1}
    assert docs.read_text() == ("# Benchmarks\n\n<!-- bench:render -->\n| new |\n<!-- /bench:render -->\n\n"
                                "<!-- bench:farm -->\nfarm table\n<!-- /bench:farm -->\n")


def test_publish_without_a_section_for_the_table_is_an_error(tmp_path):
    docs = tmp_path / "benchmarks.md"
    docs.write_text("# Benchmarks\n")
    with pytest.raises(MetaSimError, match="bench:nams"):
        publish({}, tmp_path / "nams.json", "t", "nams", docs)
    assert docs.read_text() == "# Benchmarks\n" and not (tmp_path / "nams.json").exists()


def test_the_docs_page_has_one_section_per_benchmark():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "benchmarks.md").read_text()
    for name in ("render", "nams", "reference", "tradeoff", "farm", "infer", "task", "realism", "roof-finder",
                 "stability", "appearance"):
        assert text.count(f"<!-- bench:{name} -->") == 1 and text.count(f"<!-- /bench:{name} -->") == 1
