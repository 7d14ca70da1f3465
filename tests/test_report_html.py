"""``report.html``: every run, campaign and comparison writes one page with its plots inside,
and a real browser (headless chromium) shows it without a broken image or a console error."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from slamfront.recipe import build_pipeline, parse_recipe
from slamfront.report.headline import headline
from slamfront.report.html import markdown_to_html, write_html
from slamfront.runtime import RunResult, run_pipeline
from tests.browser import open_page
from tests.helpers import small_synthetic_recipe


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> RunResult:
    raw = small_synthetic_recipe()
    raw["eval"] = {"plots": True}
    recipe = parse_recipe(raw, "small.yaml")
    out = tmp_path_factory.mktemp("html")
    return run_pipeline(build_pipeline(recipe, "small.yaml"), "small.yaml", out, progress=False)


def test_a_run_writes_a_self_contained_page_beside_report_md(run: RunResult) -> None:
    assert run.html_path == run.out_dir / "report.html"
    page = run.html_path.read_text()
    figures = re.findall(r"!\[[^\]]*\]\(([^)]+\.png)\)", run.report_path.read_text())
    assert len(figures) >= 3
    assert page.count('<img src="data:image/png;base64,') == len(figures)  # inlined, nothing to fetch
    assert not re.search(r'src="(?!data:)', page)
    headline, recipe = page.index('id="headline"'), page.index('id="recipe"')
    assert headline < page.index('id="loop-closure"') < recipe  # headline first, the recipe at the end
    assert "name: small" in page[recipe:]


def test_the_report_renders_in_a_real_browser(run: RunResult) -> None:
    page = open_page(run.html_path)
    assert page.console_errors == []
    assert page.broken_images == [] and page.n_images >= 3
    sentences = headline(run.metrics)  # what the console printed, the report's headline too
    assert len(sentences) >= 2 and all(sentence in page.text for sentence in sentences)
    assert "headline" not in page.tables  # sentences, not a table of raw metric keys
    assert page.title == "small" and "Time per stage" in page.text


def test_the_browser_check_notices_a_broken_page(tmp_path: Path) -> None:
    bad = tmp_path / "bad.html"
    bad.write_text(
        '<!DOCTYPE html><html><head><title>bad</title><link rel="icon" href="data:,"></head><body>'
        '<img src="missing.png" alt="gone"><img src="data:image/png;base64,AAAA" alt="corrupt">'
        '<script>console.error("boom")</script></body></html>'
    )
    page = open_page(bad)
    assert page.broken_images == ["gone", "corrupt"]
    assert "boom" in page.console_errors and any("missing.png" in e for e in page.console_errors)


def test_the_markdown_subset(tmp_path: Path) -> None:
    (tmp_path / "plot.png").write_bytes(b"\x89PNG fake")
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "report.md").write_text("# other\n")
    (tmp_path / "other" / "report.html").write_text("<p>other</p>")
    body = markdown_to_html(
        "# Title\n\nSome `code <x>` and **bold** text\ncontinued.\n\n## A section\n\n"
        "| a | b |\n| --- | --- |\n| 1 \\| 2 | [run](other/report.md) |\n\n"
        "![plot](plot.png)\n\n![gone](missing.png)\n\n- one\n- two\n\n```yaml\nkey: <value>\n```\n"
        "| not a table\n",
        tmp_path,
    )
    flat = " ".join(body.split())  # CommonMark keeps the source's line breaks inside blocks
    assert '<h1 id="title">Title</h1>' in flat and '<h2 id="a-section">A section</h2>' in flat
    assert "<code>code &lt;x&gt;</code>" in flat and "<strong>bold</strong> text continued." in flat
    assert "<td>1 | 2</td>" in flat and '<a href="other/report.html">run</a>' in flat
    assert '<figure><img src="data:image/png;base64,' in flat and "(figure missing.png was not written)" in flat
    assert "<ul> <li>one</li> <li>two</li> </ul>" in flat
    assert '<pre><code class="language-yaml">key: &lt;value&gt;' in flat
    assert "<p>| not a table" in flat
    hostile = markdown_to_html('<img src=x onerror="alert(1)"> [x](javascript:alert(1))', tmp_path)
    assert "<img" not in hostile and "href=" not in hostile  # text in a report is never markup, nor a javascript: link
    (tmp_path / "page.md").write_text("# Page\n\n## One\n\ntext\n\n## Two\n\nmore\n")
    page = write_html(tmp_path / "page.md").read_text()
    assert "<title>Page</title>" in page and '<a href="#one">One</a> <a href="#two">Two</a>' in page


def _recipe(tmp_path: Path, name: str, detector: dict) -> Path:
    raw = small_synthetic_recipe()
    raw.update(name=name, loop_detector=detector)
    raw["eval"] = {"plots": True}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def test_a_comparison_links_every_run_and_renders(cli, tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    recipes = [
        _recipe(tmp_path, "strict", {"plugin": "nearest_neighbour", "params": {"threshold": 0.5}}),
        _recipe(tmp_path, "loose", {"plugin": "nearest_neighbour", "params": {"threshold": 0.05}}),
    ]
    code, stdout, stderr = cli("compare", *recipes, "-o", out, "--workers", "1", "-q")
    assert code == 0, stderr
    assert f"comparison: {out / 'comparison.html'}" in stdout
    rows = json.loads((out / "results.json").read_text())["runs"]
    for name in ("comparison.html", "report.html"):
        page = open_page(out / name)
        assert page.console_errors == [] and page.broken_images == []
        run_links = [link for link in page.links if link.endswith("/report.html")]
        assert sorted(run_links) == sorted(f"{row['run']}/report.html" for row in rows)
        assert all((out / link).is_file() for link in run_links)
    assert "report.html" in open_page(out / "comparison.html").links  # and to the campaign's page


def test_a_detector_that_accepts_nothing_is_not_given_a_precision() -> None:
    metrics = {"recall_at_100p": 0.9, "auc_pr": 0.9, "precision_at_operating_point": 0.0,
               "recall_at_operating_point": 0.0, "n_accepted": 0, "accept_threshold": 0.9, "accept_auto": 0}
    line = next(s for s in headline(metrics) if s.startswith("loop closure"))
    assert "it accepts 0 answers (no loop closure reaches its threshold)" in line and "precision 0.000" not in line
    metrics.update(n_accepted=3, precision_at_operating_point=1.0, recall_at_operating_point=0.5)
    line = next(s for s in headline(metrics) if s.startswith("loop closure"))
    assert "it accepts 3 answers: precision 1.000, recall 0.500" in line
