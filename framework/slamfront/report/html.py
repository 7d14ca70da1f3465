"""``report.html``: a report as one self-contained page a browser opens.

The Markdown reports (a run's ``report.md``, a campaign's ``report.md``, a comparison's
``comparison.md``) are written by slamfront itself, in a small subset of Markdown:
headings, pipe tables, fenced code, bullet lists, paragraphs, images on a line of their
own, and inline code, bold and links. :func:`markdown_to_html` converts exactly that
subset, so no Markdown library is needed. :func:`write_html` writes the page beside the
Markdown file: the plots inlined as ``data:`` URIs (the file can be mailed or moved on
its own), a contents list of the sections, and links to other reports (``.md``) pointed
at their ``.html`` twins. A figure that is missing becomes a note, never a broken image.
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from slamfront.outputs import write_atomically

_MIME = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}

_STYLE = """
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
"""

_IMAGE_LINE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<src>[^)\s]+)\)$")
_INLINE_IMAGE = re.compile(r"!\[(?P<alt>[^\]]*)\]\((?P<src>[^)\s]+)\)")
_LINK = re.compile(r"\[(?P<text>[^\]]+)\]\((?P<href>[^)\s]+)\)")
_CODE = re.compile(r"`([^`]+)`")
_BOLD = re.compile(r"\*\*(.+?)\*\*")
_TABLE_RULE = re.compile(r"^\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?$")


def write_html(markdown_path: Path, title: str | None = None) -> Path:
    """Write ``<name>.html`` beside ``markdown_path`` (a report slamfront wrote) and return it.

    Written to a temporary file and renamed, so a reader never sees half a page.
    """
    markdown_path = Path(markdown_path)
    text = markdown_path.read_text()
    heading = next((line[2:].strip() for line in text.splitlines() if line.startswith("# ")), markdown_path.stem)
    page = render_page(text, markdown_path.parent, title or heading)
    return write_atomically(markdown_path.with_suffix(".html"), page)


def render_page(markdown: str, folder: Path, title: str) -> str:
    """The whole page: head with the style, the contents list, the converted body."""
    body = markdown_to_html(markdown, folder)
    sections = re.findall(r'<h2 id="([^"]+)">(.*?)</h2>', body)
    contents = ""
    if len(sections) > 1:
        links = " ".join(f'<a href="#{anchor}">{label}</a>' for anchor, label in sections)
        contents = f'<nav class="contents">Contents: {links}</nav>\n'
    # the contents go right after the title and its first paragraphs, before the first section
    first_section = body.find("<h2")
    if first_section >= 0:
        body = body[:first_section] + contents + body[first_section:]
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n"
        '<link rel="icon" href="data:,">\n'  # no favicon request: a file:// page has nothing to fetch
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n{body}</body>\n</html>\n"
    )


def markdown_to_html(markdown: str, folder: Path) -> str:
    """Convert slamfront's Markdown subset to HTML; images and links resolve against ``folder``."""
    out: list[str] = []
    lines = markdown.splitlines()
    anchors: set[str] = set()
    k = 0
    while k < len(lines):
        line = lines[k]
        stripped = line.strip()
        if not stripped:
            k += 1
        elif stripped.startswith("```"):
            language = stripped[3:].strip()
            end = next((j for j in range(k + 1, len(lines)) if lines[j].strip().startswith("```")), len(lines))
            code = html.escape("\n".join(lines[k + 1 : end]))
            attribute = f' class="language-{html.escape(language)}"' if language else ""
            out.append(f"<pre><code{attribute}>{code}</code></pre>")
            k = end + 1
        elif re.match(r"^#{1,6} ", stripped):
            level = len(stripped) - len(stripped.lstrip("#"))
            content = stripped[level:].strip()
            anchor = _anchor(content, anchors)
            out.append(f'<h{level} id="{anchor}">{_inline(content, folder)}</h{level}>')
            k += 1
        elif stripped.startswith("|") and k + 1 < len(lines) and _TABLE_RULE.match(lines[k + 1].strip()):
            end = k + 2
            while end < len(lines) and lines[end].strip().startswith("|"):
                end += 1
            out.append(_table(lines[k], lines[k + 2 : end], folder))
            k = end
        elif _IMAGE_LINE.match(stripped):
            match = _IMAGE_LINE.match(stripped)
            assert match is not None
            out.append(_figure(match["alt"], match["src"], folder))
            k += 1
        elif stripped.startswith("- "):
            items = []
            while k < len(lines) and lines[k].strip().startswith("- "):
                items.append(f"<li>{_inline(lines[k].strip()[2:], folder)}</li>")
                k += 1
            out.append("<ul>" + "".join(items) + "</ul>")
        else:
            paragraph = [stripped]  # at least this line (a lone "|..." without a rule is text)
            k += 1
            while k < len(lines) and lines[k].strip() and not _starts_block(lines, k):
                paragraph.append(lines[k].strip())
                k += 1
            out.append(f"<p>{_inline(' '.join(paragraph), folder)}</p>")
    return "\n".join(out) + "\n"


def _starts_block(lines: list[str], k: int) -> bool:
    stripped = lines[k].strip()
    return (
        stripped.startswith(("```", "- ", "|"))
        or bool(re.match(r"^#{1,6} ", stripped))
        or bool(_IMAGE_LINE.match(stripped))
    )


def _anchor(text: str, taken: set[str]) -> str:
    base = re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "section"
    anchor, n = base, 2
    while anchor in taken:
        anchor, n = f"{base}-{n}", n + 1
    taken.add(anchor)
    return anchor


def _cells(row: str) -> list[str]:
    """A table row's cells; ``\\|`` is a literal bar inside a cell."""
    inner = row.strip()
    inner = inner[1:] if inner.startswith("|") else inner
    inner = inner[:-1] if inner.endswith("|") and not inner.endswith("\\|") else inner
    return [cell.strip().replace("\\|", "|") for cell in re.split(r"(?<!\\)\|", inner)]


def _table(header: str, rows: list[str], folder: Path) -> str:
    head = "".join(f"<th>{_inline(c, folder)}</th>" for c in _cells(header))
    body = "".join("<tr>" + "".join(f"<td>{_inline(c, folder)}</td>" for c in _cells(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _data_uri(src: str, folder: Path) -> str | None:
    """The file ``src`` (relative to ``folder``) as a ``data:`` URI; None when it is not there."""
    if re.match(r"^[a-z]+:", src):  # already a URI: left to the browser
        return src
    path = folder / src
    mime = _MIME.get(path.suffix.lower())
    if mime is None or not path.is_file():
        return None
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode('ascii')}"


def _figure(alt: str, src: str, folder: Path) -> str:
    uri = _data_uri(src, folder)
    if uri is None:
        return f'<p class="missing">(figure {html.escape(src)} was not written)</p>'
    return (f'<figure><img src="{html.escape(uri)}" alt="{html.escape(alt)}">'
            f"<figcaption>{html.escape(src)}</figcaption></figure>")


def _href(target: str, folder: Path) -> str:
    """A link to another report's Markdown points at its HTML twin when that exists."""
    path, _, fragment = target.partition("#")
    if path.endswith(".md") and not re.match(r"^[a-z]+:", path):
        twin = path[:-3] + ".html"
        if (folder / twin).is_file():
            return twin + (f"#{fragment}" if fragment else "")
    return target


def _inline(text: str, folder: Path) -> str:
    """Inline code, images, links and bold; everything else escaped."""
    pieces = re.split(r"(`[^`]+`)", text)
    out = []
    for piece in pieces:
        if _CODE.fullmatch(piece):
            out.append(f"<code>{html.escape(piece[1:-1])}</code>")
            continue
        escaped = html.escape(piece, quote=False)

        def image(match: re.Match[str]) -> str:
            uri = _data_uri(html.unescape(match["src"]), folder)
            if uri is None:
                return f'<span class="missing">(figure {match["src"]} was not written)</span>'
            return f'<img src="{html.escape(uri)}" alt="{match["alt"]}">'

        def link(match: re.Match[str]) -> str:
            return f'<a href="{html.escape(_href(html.unescape(match["href"]), folder))}">{match["text"]}</a>'

        escaped = _INLINE_IMAGE.sub(image, escaped)
        escaped = _LINK.sub(link, escaped)
        out.append(_BOLD.sub(r"<strong>\1</strong>", escaped))
    return "".join(out)
