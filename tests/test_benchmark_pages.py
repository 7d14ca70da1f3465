"""The benchmark pages' bookkeeping (benchmarks/common.py): a run of one part of a benchmark
rewrites only its section, in its place."""

from __future__ import annotations

import importlib.util
from pathlib import Path

COMMON = Path(__file__).resolve().parents[1] / "benchmarks" / "common.py"


def _common():
    spec = importlib.util.spec_from_file_location("bench_common", COMMON)
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_a_rerun_section_keeps_its_place_and_the_others_are_marked_earlier(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# T\n\n## Route\nold route\n\n## Cached\nold cached\n\nMachine: box A\n")
    merged = _common().merge_sections(page, "## Cached\nnew cached\n")
    assert merged.index("## Route (earlier run)") < merged.index("## Cached\nnew cached")
    assert "Machine: box A (The machine of that run.)\nold route" in merged
    assert "old cached" not in merged
    page.write_text(f"# T\n\n{merged}\nMachine: box B\n")
    again = _common().merge_sections(page, "## Route\nnew route\n")
    assert again.index("## Route\nnew route") < again.index("## Cached (earlier run)")
    assert "Machine: box B (The machine of that run.)\nnew cached" in again
    assert again.count("(earlier run)") == 1


def test_a_new_section_comes_first(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text("# T\n\n## Old\nold\n\nMachine: box A\n")
    merged = _common().merge_sections(page, "## New\nnew\n")
    assert merged.startswith("## New\nnew") and "## Old (earlier run)" in merged
