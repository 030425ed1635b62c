"""The report as one self-contained HTML file: every figure embedded as a base64 PNG (or inline SVG),
the style inline, no script and no external reference, so it opens from a mail attachment or a USB
stick as it does in the build."""

from __future__ import annotations

import base64
import re
from collections.abc import Callable, Sequence
from html import escape

from rxcomm.reporting.document import Report, Section, Table, Verdict, VerdictRow
from rxcomm.reporting.markdown import (
    ACCEPTANCE_TITLE,
    CHECKS_INTRO,
    CHECKS_TITLE,
    verdict_columns,
)

_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 70rem; margin: 2rem auto; padding: 0 1rem;
       color: #222; line-height: 1.4; }
table { border-collapse: collapse; margin: 0.6rem 0 1rem; font-size: 0.92rem; }
th, td { border: 1px solid #ccc; padding: 0.25rem 0.5rem; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
caption { text-align: left; font-weight: 600; padding: 0.2rem 0; }
td.pass { background: #dff3df; } td.fail { background: #f8d7d7; font-weight: 600; }
td.not-measured { background: #eee; color: #666; font-style: italic; }
figure { margin: 0.5rem 0 1.5rem; } figure img, figure svg { max-width: 100%; height: auto; }
figcaption { font-size: 0.85rem; color: #555; } p.missing { color: #a00; font-style: italic; }
p.headline { font-size: 1.5rem; font-weight: 700; padding: 0.4rem 0.8rem; margin: 0.5rem 0 1rem; }
p.accepted { background: #dff3df; border-left: 0.4rem solid #2a7d2a; }
p.not-accepted { background: #f8d7d7; border-left: 0.4rem solid #a00; }
"""

ImageLoader = Callable[[str], bytes | None]


def _text(text: object) -> str:
    """Escaped text, Markdown's `code` spans as <code>."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", escape(str(text)))


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], caption: str = "", cls: str = "") -> str:
    out = [f'<table class="{cls}">' if cls else "<table>"]
    if caption:
        out.append(f"<caption>{escape(caption)}</caption>")
    out.append("<tr>" + "".join(f"<th>{escape(h)}</th>" for h in header) + "</tr>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td>{_text(c)}</td>" for c in row) + "</tr>")
    return "\n".join([*out, "</table>"])


def _verdict_table(rows: Sequence[VerdictRow], table_id: str) -> str:
    header, cells = verdict_columns(rows)
    col = header.index("verdict")
    out = [f'<table id="{table_id}">', "<tr>" + "".join(f"<th>{escape(h)}</th>" for h in header) + "</tr>"]
    for row, r in zip(cells, rows, strict=True):
        tds = []
        for i, c in enumerate(row):
            cls = {Verdict.passed: "pass", Verdict.failed: "fail"}.get(r.verdict, "not-measured")
            tds.append(f'<td class="{cls}">{escape(c)}</td>' if i == col else f"<td>{_text(c)}</td>")
        out.append("<tr>" + "".join(tds) + "</tr>")
    return "\n".join([*out, "</table>"])


def _figure(name: str, title: str, load: ImageLoader) -> str:
    data = load(name)
    if data is None:
        return f'<p class="missing">figure {escape(name)}: not produced in this build</p>'
    if name.endswith(".svg"):
        body = data.decode("utf-8")
    else:
        b64 = base64.b64encode(data).decode("ascii")
        body = f'<img alt="{escape(title)}" src="data:image/png;base64,{b64}">'
    return f"<figure>{body}<figcaption>{escape(name)}</figcaption></figure>"


def _tables(tables: Sequence[Table]) -> list[str]:
    return [_table(t.header, t.rows, t.caption) for t in tables]


def _section(sec: Section, load: ImageLoader) -> list[str]:
    out = [f"<section><h2>{escape(sec.title)}</h2>"]
    if sec.figures:
        out.append(_table(["figure", "value"], [[f.what, f.ours] for f in sec.figures]))
    out += _tables(sec.tables)
    if sec.note:
        out.append(f"<p>{_text(sec.note)}</p>")
    out += [_figure(name, sec.title, load) for name in sec.all_images()]
    return [*out, "</section>"]


def render(report: Report, load: ImageLoader) -> str:
    """HTML text; `load(name)` returns the bytes of a figure of the build (None: not there). The
    headline (the verdict line, `p#headline`) is the first element after the title."""
    out = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{escape(report.title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{escape(report.title)}</h1>",
    ]
    if report.headline:
        cls = "accepted" if report.headline == "ACCEPTED" else "not-accepted"
        out.append(f'<p id="headline" class="headline {cls}">{escape(report.headline)}</p>')
    out += [f"<p>{_text(p)}</p>" for p in report.preamble.split("\n\n")]
    if report.acceptance:
        out += [f"<h2>{escape(ACCEPTANCE_TITLE)}</h2>", _verdict_table(report.acceptance, "acceptance")]
        out += [f"<p>{_text(report.acceptance_note)}</p>"] if report.acceptance_note else []
    for sec in report.acceptance_sections:
        out += _section(sec, load)
    if report.verdict:
        out += [f"<h2>{escape(CHECKS_TITLE)}</h2>", f"<p>{_text(CHECKS_INTRO)}</p>"]
        out.append(_verdict_table(report.verdict, "checks"))
        out += [f"<p>{_text(report.verdict_note)}</p>"] if report.verdict_note else []
    for sec in report.sections:
        out += _section(sec, load)
    out += [
        '<section><h2 id="paper">Comparison with the paper</h2>',
        f"<p>{escape(report.paper_note)}</p>",
        _table(["stage", "figure", "rxcomm", "paper"], report.paper_rows()),
        "</section></body></html>",
    ]
    return "\n".join(out) + "\n"
