"""``report.html``: a report as one self-contained page a browser opens.

The Markdown reports (a run's ``report.md``, a campaign's ``report.md``, a comparison's
``comparison.md``) become HTML through markdown-it-py (CommonMark with tables; raw HTML in
the text is escaped, never passed through) and a Jinja2 page template. Three things are
slamfront's own, as render rules: figures are inlined as ``data:`` URIs (the file can be
mailed or moved on its own) and a figure that is missing becomes a note, never a broken
image; a link to another report (``.md``) points at its ``.html`` twin when there is one;
headings get ids, and the page opens with a contents list of its sections.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from jinja2 import Environment
from markdown_it import MarkdownIt
from markdown_it.renderer import RendererHTML
from markdown_it.token import Token
from markdown_it.utils import EnvType, OptionsDict
from markupsafe import Markup

from slamfront.outputs import write_atomically

_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}

_PAGE = Environment(autoescape=True, keep_trailing_newline=True).from_string("""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<link rel="icon" href="data:,">
<title>{{ title }}</title>
<style>
body { font: 15px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1d232a; margin: 0 auto;
       max-width: 1100px; padding: 1.5em 2em 4em; }
h1 { font-size: 1.7em; margin-bottom: .2em; } h2 { border-bottom: 1px solid #d8dee4; padding-bottom: .2em;
margin-top: 2em; } h3 { margin-top: 1.5em; }
table { border-collapse: collapse; margin: .8em 0; font-size: 13px; }
th, td { border: 1px solid #d8dee4; padding: 3px 9px; text-align: left; vertical-align: top; }
th { background: #f3f5f7; } tr:nth-child(even) td { background: #fafbfc; }
td:not(:first-child) { font-variant-numeric: tabular-nums; }
code { background: #f3f5f7; border-radius: 3px; padding: 0 3px; font-size: 90%; }
pre { background: #f6f8fa; border: 1px solid #d8dee4; border-radius: 4px; padding: .8em; overflow-x: auto;
      font-size: 12px; line-height: 1.35; } pre code { background: none; padding: 0; }
figure { margin: 1em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eef0f2; }
figcaption { color: #57606a; font-size: 12px; }
nav.contents { background: #f6f8fa; border: 1px solid #d8dee4; border-radius: 4px; padding: .4em 1em;
               margin: 1em 0; font-size: 13px; } nav.contents a { margin-right: 1em; }
.missing { color: #9a6700; }
</style>
</head>
<body>
{{ opening }}
{%- if sections|length > 1 %}
<nav class="contents">Contents:{% for anchor, label in sections %} <a href="#{{ anchor }}">{{ label }}</a>{% endfor %}</nav>
{%- endif %}
{{ rest }}</body>
</html>
""")


def write_html(
    markdown_path: Path, title: str | None = None, announce: Callable[[Path, int, str], None] | None = None
) -> Path:
    """Write ``<name>.html`` beside ``markdown_path`` (a report slamfront wrote) and return it.

    Written to a temporary file and renamed, so a reader never sees half a page
    (``announce``: see :func:`slamfront.outputs.write_atomically`).
    """
    markdown_path = Path(markdown_path)
    text = markdown_path.read_text()
    heading = next((line[2:].strip() for line in text.splitlines() if line.startswith("# ")), markdown_path.stem)
    page = render_page(text, markdown_path.parent, title or heading)
    return write_atomically(markdown_path.with_suffix(".html"), page, announce)


def render_page(markdown: str, folder: Path, title: str) -> str:
    """The whole page: the contents list after the title and its first paragraphs, before the first section."""
    parser = _parser()
    env: dict[str, Any] = {"folder": folder, "anchors": set()}
    tokens = parser.parse(markdown, env)
    first = next((i for i, t in enumerate(tokens) if t.type == "heading_open" and t.tag == "h2"), len(tokens))
    sections = [(t.attrs["id"], tokens[i + 1].content) for i, t in enumerate(tokens)
                if t.type == "heading_open" and t.tag == "h2"]
    return _PAGE.render(
        title=title, sections=sections,
        opening=Markup(parser.renderer.render(tokens[:first], parser.options, env)),
        rest=Markup(parser.renderer.render(tokens[first:], parser.options, env)),
    )


def markdown_to_html(markdown: str, folder: Path) -> str:
    """The body of a page: images and links resolve against ``folder``."""
    return _parser().render(markdown, {"folder": folder, "anchors": set()})


def _parser() -> MarkdownIt:
    parser = MarkdownIt("commonmark", {"html": False}).enable("table")
    parser.core.ruler.push("slamfront_anchors_and_figures", _anchors_and_figures)
    parser.add_render_rule("image", _image)
    parser.add_render_rule("link_open", _link_open)
    return parser


def _anchors_and_figures(state: Any) -> None:
    """Give every heading an id; mark paragraphs that hold one image only as figures."""
    tokens: list[Token] = state.tokens
    for i, token in enumerate(tokens):
        if token.type == "heading_open":
            token.attrSet("id", _anchor(tokens[i + 1].content, state.env["anchors"]))
        elif (token.type == "paragraph_open" and i + 2 < len(tokens) and tokens[i + 1].children
              and [c.type for c in tokens[i + 1].children] == ["image"]):
            token.hidden = tokens[i + 2].hidden = True  # no <p> around the <figure>
            tokens[i + 1].children[0].meta["figure"] = True


def _anchor(text: str, taken: set[str]) -> str:
    base = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"
    anchor, n = base, 2
    while anchor in taken:
        anchor, n = f"{base}-{n}", n + 1
    taken.add(anchor)
    return anchor


def _image(self: RendererHTML, tokens: Sequence[Token], idx: int, options: OptionsDict, env: EnvType) -> str:
    token = tokens[idx]
    src = str(token.attrGet("src") or "")
    alt = self.renderInlineAsText(token.children or [], options, env)
    uri = _data_uri(src, env["folder"])
    if uri is None:
        note = f"(figure {src} was not written)"
        return str(Markup('<p class="missing">{}</p>' if token.meta.get("figure") else '<span class="missing">{}</span>')
                   .format(note))
    image = Markup('<img src="{}" alt="{}">').format(uri, alt)
    if not token.meta.get("figure"):
        return str(image)
    return str(Markup("<figure>{}<figcaption>{}</figcaption></figure>\n").format(image, src))


def _link_open(self: RendererHTML, tokens: Sequence[Token], idx: int, options: OptionsDict, env: EnvType) -> str:
    token = tokens[idx]
    token.attrSet("href", _href(str(token.attrGet("href") or ""), env["folder"]))
    return self.renderToken(tokens, idx, options, env)


def _data_uri(src: str, folder: Path) -> str | None:
    """The file ``src`` (relative to ``folder``) as a ``data:`` URI; None when it is not there."""
    if re.match(r"^[a-z]+:", src):  # already a URI: left to the browser
        return src
    path = folder / src
    mime = _MIME.get(path.suffix.lower())
    if mime is None or not path.is_file():
        return None
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _href(target: str, folder: Path) -> str:
    """A link to another report's Markdown points at its HTML twin when that exists."""
    path, _, fragment = target.partition("#")
    if path.endswith(".md") and not re.match(r"^[a-z]+:", path):
        twin = path[:-3] + ".html"
        if (folder / twin).is_file():
            return twin + (f"#{fragment}" if fragment else "")
    return target


__all__ = ["markdown_to_html", "render_page", "write_html"]
