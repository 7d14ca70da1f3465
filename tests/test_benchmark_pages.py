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


def _generalisation():
    spec = importlib.util.spec_from_file_location("bench_generalisation", COMMON.parent / "bench_generalisation.py")
    module = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def test_the_operating_point_rule_and_its_plot(tmp_path: Path) -> None:
    bench = _generalisation()

    def run(method: str, r100: float, precision: float, recall: float, accepted: int) -> dict:
        return dict(method=method, variant="v", recall_at_100p=r100, precision_at_operating_point=precision,
                    recall_at_operating_point=recall, n_accepted=accepted)

    met = run("seqslam", 0.6, 1.0, 0.3, 30)
    too_few = run("seqslam", 0.6, 1.0, 0.2, 20)  # needs 0.28
    wrong = run("bow_bayes", 0.1, 0.9, 0.5, 10)
    nothing_needed = run("bow_bayes", 0.03, 0.0, 0.0, 0)  # accepts nothing where nothing is needed
    assert [bench.misses_rule(r) for r in (met, too_few, wrong, nothing_needed)] == [False, True, True, False]
    path = tmp_path / "points.png"
    bench.plot_operating_points([met, too_few, wrong, nothing_needed], {"seqslam": {"v"}}, path, "test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
