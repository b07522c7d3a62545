"""A self-contained HTML page from the Markdown a diagnosis report is written in.

:func:`markdown_to_html` renders the subset of Markdown that
:mod:`realitygap.diagnosis.report.writer` writes — headings, paragraphs, bullet lists,
pipe tables, images, ``**bold**``, ``*italic*``, ``` `code` ```, two-space line
breaks and ``<details>`` blocks — and embeds every image as a base64 PNG
``data:`` URI, so the one file can be mailed or opened anywhere.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Callable
from pathlib import Path

__all__ = ["markdown_to_html"]

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; max-width: 70em;
       margin: 2em auto; padding: 0 1em; line-height: 1.45; color: #222; }
h1 { border-bottom: 2px solid #ccc; padding-bottom: .2em; }
h2 { border-bottom: 1px solid #ddd; padding-bottom: .15em; margin-top: 1.6em; }
table { border-collapse: collapse; margin: .6em 0; font-size: .92em; }
th, td { border: 1px solid #ccc; padding: .25em .55em; text-align: left; vertical-align: top; }
th { background: #f3f3f3; }
figure { margin: 1em 0; }
figure img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-style: italic; color: #555; }
code { background: #f4f4f4; padding: 0 .2em; }
.summary { background: #f6f9fc; border-left: 4px solid #4a7ab5; padding: .4em 1em; }
"""

_IMAGE = re.compile(r"^!\[(?P<alt>[^\]]*)\]\((?P<src>[^)\s]+)\)$")


def _inline(text: str) -> str:
    """Escape ``text`` and render code, bold and italic spans."""
    parts = re.split(r"(`[^`]+`)", text)
    out = []
    for part in parts:
        if part.startswith("`") and part.endswith("`") and len(part) > 1:
            out.append(f"<code>{html.escape(part[1:-1])}</code>")
            continue
        s = html.escape(part, quote=False)
        s = re.sub(r"\*\*(.+?)\*\*", r"<strong>\1</strong>", s)
        s = re.sub(r"(?<![\w*])\*(?!\s)(.+?)(?<!\s)\*(?![\w*])", r"<em>\1</em>", s)
        out.append(s)
    return "".join(out)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def markdown_to_html(
    markdown: str, image_bytes: Callable[[str], bytes] | Path, title: str = "Report"
) -> str:
    """Render ``markdown`` as one HTML page with its images embedded.

    Parameters
    ----------
    markdown : str
        Text in the subset described in the module docstring.
    image_bytes : callable or Path
        ``image_bytes(src)`` returns the PNG bytes of an image reference, or a
        folder the references are relative to.
    title : str
        The page title.

    Returns
    -------
    str
        A complete HTML document; every ``<img>`` has a ``data:image/png;base64`` source.

    Raises
    ------
    FileNotFoundError
        If an image the Markdown refers to does not exist.
    """
    read: Callable[[str], bytes]
    if isinstance(image_bytes, Path):
        folder = image_bytes

        def read_file(src: str) -> bytes:
            path = folder / src
            if not path.is_file():
                raise FileNotFoundError(f"the report refers to an image {path} that does not exist")
            return path.read_bytes()

        read = read_file
    else:
        read = image_bytes

    body: list[str] = []
    lines = markdown.splitlines()
    para: list[str] = []
    i = 0

    def flush_para() -> None:
        if para:
            text = "<br>\n".join(
                _inline(p.rstrip()) if p.endswith("  ") else _inline(p) for p in para
            )
            body.append(f"<p>{text}</p>")
            para.clear()

    while i < len(lines):
        line = lines[i]
        stripped = line.strip()
        if not stripped:
            flush_para()
            i += 1
            continue
        if stripped.startswith(("<details", "</details")):
            flush_para()
            body.append(stripped)  # the report's own <details> blocks, as written
            i += 1
            continue
        heading = re.match(r"^(#{1,6})\s+(.*)$", stripped)
        if heading:
            flush_para()
            level = len(heading.group(1))
            body.append(f"<h{level}>{_inline(heading.group(2))}</h{level}>")
            i += 1
            continue
        image = _IMAGE.match(stripped)
        if image:
            flush_para()
            data = base64.b64encode(read(image.group("src"))).decode("ascii")
            alt = html.escape(image.group("alt"))
            body.append(
                f'<figure><img src="data:image/png;base64,{data}" alt="{alt}">'
                f"<figcaption>{alt}</figcaption></figure>"
            )
            i += 1
            # the Markdown repeats the caption in italics below the image
            while i < len(lines) and not lines[i].strip():
                i += 1
            if i < len(lines) and lines[i].strip() == f"*{image.group('alt')}*":
                i += 1
            continue
        if (
            stripped.startswith("|")
            and i + 1 < len(lines)
            and re.match(r"^\|[\s|:-]+\|$", lines[i + 1].strip())
        ):
            flush_para()
            head = _cells(stripped)
            rows = []
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                rows.append(_cells(lines[i]))
                i += 1
            out = [
                "<table><thead><tr>",
                *(f"<th>{_inline(c)}</th>" for c in head),
                "</tr></thead><tbody>",
            ]
            for r in rows:
                out.append("<tr>" + "".join(f"<td>{_inline(c)}</td>" for c in r) + "</tr>")
            out.append("</tbody></table>")
            body.append("".join(out))
            continue
        if stripped.startswith("- "):
            flush_para()
            items = []
            while i < len(lines) and lines[i].strip().startswith("- "):
                items.append(f"<li>{_inline(lines[i].strip()[2:])}</li>")
                i += 1
            body.append("<ul>" + "".join(items) + "</ul>")
            continue
        if stripped.startswith("> "):
            flush_para()
            quoted = []
            while i < len(lines) and lines[i].strip().startswith(">"):
                quoted.append(_inline(lines[i].strip()[1:].strip()))
                i += 1
            body.append('<div class="summary">' + "".join(f"<p>{q}</p>" for q in quoted) + "</div>")
            continue
        para.append(line)
        i += 1
    flush_para()
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        f"<title>{html.escape(title)}</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )
