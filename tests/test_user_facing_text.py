"""User-facing text cites the methods by author and year, never by internal labels.

README, docs, recipes, sweeps, the Foxglove layout, the package's code (help texts,
messages, report templates, docstrings) and the example plugin are what a user reads.
None of it may speak of "seed 000", "issue 6", a ``../shared`` path or a design file
that does not ship.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from slamfront.cli import build_parser

REPO = Path(__file__).resolve().parents[1]
USER_FACING = ("README.md", "docs", "recipes", "sweeps", "foxglove", "framework", "plugins", "examples", "benchmarks")
SUFFIXES = {".md", ".py", ".yaml", ".yml", ".json", ".txt", ".toml", ".html"}
FORBIDDEN = re.compile(
    r"\b[Ss]eeds? (?:0\d\d|§|paper|thesis|fig|eq|ch|table|Table)|\bthe seed(?:'s)?\b|\bseeds?/0\d\d|\.\./shared\b|shared/seeds"
    r"|\b[Ii]ssues? \d+\b|\bDESIGN\.md\b"
)


def _user_facing_files() -> list[Path]:
    files: list[Path] = []
    for entry in USER_FACING:
        path = REPO / entry
        candidates = [path] if path.is_file() else sorted(path.rglob("*"))
        files += [
            p for p in candidates
            if p.is_file() and p.suffix in SUFFIXES and ".egg-info" not in p.parts and "__pycache__" not in p.parts
        ]
    return files


def test_user_facing_files_cite_authors_not_internal_labels() -> None:
    offenders = []
    for path in _user_facing_files():
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
            if FORBIDDEN.search(line):
                offenders.append(f"{path.relative_to(REPO)}:{number}: {line.strip()[:120]}")
    assert not offenders, "internal labels in user-facing text:\n" + "\n".join(offenders)


def _all_help_texts() -> str:
    parser = build_parser()
    texts = [parser.format_help()]
    for action in parser._subparsers._group_actions:  # noqa: SLF001 - argparse keeps sub-parsers here
        for sub in action.choices.values():
            texts.append(sub.format_help())
    return "\n".join(texts)


def test_cli_help_cites_authors_not_internal_labels() -> None:
    found = FORBIDDEN.findall(_all_help_texts())
    assert not found, f"internal labels in --help: {found}"


@pytest.mark.parametrize("line", ["see seed 000 §3", "the detectors of seeds 000/SeqSLAM", "posterior (seed fig. 7)", "as in the seed's Table 4.1", "(issue 9)", "../shared/data", "DESIGN.md"])
def test_the_pattern_catches_each_kind_of_label(line: str) -> None:
    assert FORBIDDEN.search(line)


@pytest.mark.parametrize("line", ["world seed 3", "seed: 7", "--seed 12", "a seeded generator"])
def test_the_pattern_leaves_random_seeds_alone(line: str) -> None:
    assert not FORBIDDEN.search(line)
