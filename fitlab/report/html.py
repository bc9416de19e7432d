"""The report's HTML: one self-contained ``index.html`` (inline CSS, figures embedded as PNG
data: URIs, no scripts, no external URLs, fonts or style sheets). Pure string building."""

from __future__ import annotations

import base64
import html
import struct
from typing import NamedTuple

CSS = """
body { font-family: "DejaVu Sans", Arial, Helvetica, sans-serif; margin: 1.2em auto;
       max-width: 1100px; padding: 0 1em; color: #222; line-height: 1.4; }
h1 { font-size: 1.5em; border-bottom: 2px solid #444; padding-bottom: .2em; }
h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #aaa; }
h3 { font-size: 1.08em; margin-top: 1.3em; }
table { border-collapse: collapse; margin: .6em 0; font-size: .88em; }
th, td { border: 1px solid #bbb; padding: .22em .55em; text-align: left; vertical-align: top; }
th { background: #eee; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0 1.6em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: .86em; color: #333; max-width: 60em; }
figure.half { display: inline-block; vertical-align: top; width: 48%; margin-right: 1.5%; }
.warning { background: #fff3cd; border: 2px solid #c9302c; padding: .5em 1em; margin: 1em 0; }
.warning strong { color: #a00; }
.note { background: #eef4fb; border-left: 4px solid #4a7ab5; padding: .4em .8em; margin: .8em 0; }
nav ul { columns: 2; font-size: .9em; }
code { background: #f4f4f4; padding: 0 .2em; }
.small { font-size: .85em; color: #555; }
"""


class FigureEntry(NamedTuple):
    name: str  # file stem: NAME.png and NAME.svg beside index.html
    caption: str  # what the figure shows (plain text)
    alt: str  # alternative text for the image (plain text)
    png: bytes
    svg: bytes


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def png_size(png: bytes) -> tuple[int, int]:
    """(width, height) from a PNG's IHDR chunk."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    return struct.unpack(">II", png[16:24])


def figure_html(fig: FigureEntry, half: bool = False) -> str:
    """A figure with its caption; ``half``: two such figures share a row on a wide screen."""
    w, h = png_size(fig.png)
    data = base64.b64encode(fig.png).decode("ascii")
    cls = ' class="half"' if half else ""
    return (f'<figure id="{esc(fig.name)}"{cls}>\n<img src="data:image/png;base64,{data}" '
            f'width="{w}" height="{h}" alt="{esc(fig.alt)}">\n'
            f"<figcaption>{esc(fig.caption)} <span class=\"small\">(Files: "
            f"<code>{esc(fig.name)}.png</code>, <code>{esc(fig.name)}.svg</code>.)</span>"
            "</figcaption>\n</figure>\n")


def table_html(header: list, rows: list, numeric: tuple = ()) -> str:
    """A table (no header row when ``header`` is empty); cells are plain text (escaped);
    columns whose index is in ``numeric`` align right."""
    out = ["<table>"]
    if header:
        out.append("<tr>" + "".join(f"<th>{esc(h)}</th>" for h in header) + "</tr>")
    for row in rows:
        cells = []
        for k, cell in enumerate(row):
            cls = ' class="num"' if k in numeric else ""
            cells.append(f"<td{cls}>{esc(cell)}</td>")
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</table>")
    return "\n".join(out) + "\n"


def warning_html(title: str, items: list) -> str:
    lis = "".join(f"<li>{esc(i)}</li>" for i in items)
    return f'<div class="warning"><strong>{esc(title)}</strong><ul>{lis}</ul></div>\n'


def note_html(text: str) -> str:
    return f'<p class="note">{esc(text)}</p>\n'


def paragraph(text: str) -> str:
    return f"<p>{esc(text)}</p>\n"


def document(title: str, sections: list, files: list = (), lead: str = "", css: str = "") -> str:
    """``sections``: list of (anchor, heading, body HTML); ``files``: the figure files written
    beside the page (listed in a meta element, so a rebuild can remove stale ones); ``lead``:
    HTML shown first, under the title and before the contents (a fit report's answer); ``css``:
    rules added to the style sheet. Returns the whole page."""
    nav = "".join(f'<li><a href="#{esc(a)}">{esc(h)}</a></li>' for a, h, _ in sections if h)
    body = []
    for anchor, heading, content in sections:
        if heading:
            body.append(f'<section id="{esc(anchor)}">\n<h2>{esc(heading)}</h2>\n{content}'
                        "</section>\n")
        else:
            body.append(content)
    return ("<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
            '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
            '<meta name="generator" content="fitlab report">\n'
            f'<meta name="fitlab-report-files" content="{esc(" ".join(files))}">\n'
            f"<title>{esc(title)}</title>\n<style>{CSS}{css}</style>\n</head>\n<body>\n"
            f"<h1>{esc(title)}</h1>\n{lead}<nav><ul>{nav}</ul></nav>\n" + "".join(body)
            + "</body>\n</html>\n")
