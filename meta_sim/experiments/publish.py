"""One way to publish a benchmark: its JSON in ``benchmarks/``, its table on the console and in
``docs/benchmarks.md``, so that no figure in the docs is typed in by hand."""

from __future__ import annotations

import json
import re
from pathlib import Path

from ..core.errors import MetaSimError
from ..core.fileio import write_text_atomic

DOCS = Path("docs/benchmarks.md")


def _markers(section: str) -> tuple[str, str]:
    return f"<!-- bench:{section} -->", f"<!-- /bench:{section} -->"


def publish(result: dict, out: Path, table: str, section: str, docs: Path | None = DOCS) -> list[Path]:
    """Write ``result`` to ``out`` as JSON and ``table`` into ``docs`` between the markers
    ``<!-- bench:SECTION -->`` and ``<!-- /bench:SECTION -->`` (skipped when ``docs`` is None or
    does not exist). Returns the files written."""
    page = _with_section(docs, section, table) if docs is not None and Path(docs).is_file() else None
    written = [write_text_atomic(out, json.dumps(result, indent=2) + "\n")]
    if page is not None:
        written.append(write_text_atomic(docs, page))
    return written


def publish_section(page: Path, section: str, table: str) -> Path:
    """``table`` written into ``page`` (a README, say) between the markers of ``section``, alone."""
    return write_text_atomic(page, _with_section(page, section, table))


def _with_section(page: Path, section: str, table: str) -> str:
    """The text of ``page`` with ``table`` between the markers of ``section``; MetaSimError without them."""
    text = Path(page).read_text()
    start, end = _markers(section)
    pattern = re.compile(re.escape(start) + r".*?" + re.escape(end), re.S)
    if not pattern.search(text):
        raise MetaSimError(f"{page} has no section {start} ... {end} for this table; add one or pass --no-docs")
    return pattern.sub(lambda _: f"{start}\n{table.strip()}\n{end}", text, count=1)
