"""The report as Markdown: the verdict line, tables for the acceptance and the checks, each section's
figures and tables, images linked by file name (they sit beside report.md in the build)."""

from __future__ import annotations

from collections.abc import Sequence

from rxcomm.reporting.document import Report, Section, Table, VerdictRow


def _cell(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _table(header: Sequence[str], rows: Sequence[Sequence[object]]) -> list[str]:
    out = ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return out


def verdict_columns(rows: Sequence[VerdictRow]) -> tuple[list[str], list[list[str]]]:
    """Header and cells of the verdict table; the factory and ratio columns only when a row has them."""
    both = any(r.factory or r.ratio for r in rows)
    header = ["criterion", *(["factory", "commissioned", "ratio"] if both else ["measured"])]
    header += ["threshold", "verdict", "note"]
    cells = [
        [r.criterion, *([r.factory, r.measured, r.ratio] if both else [r.measured])]
        + [r.threshold, r.verdict.value, r.note]
        for r in rows
    ]
    return header, cells


def _named_table(t: Table) -> list[str]:
    return ([f"**{t.caption}**", ""] if t.caption else []) + _table(t.header, t.rows) + [""]


CHECKS_TITLE = "Commissioning checks"
CHECKS_INTRO = (
    "rxcomm's own checks of its stages against their targets (rxcomm/reporting/targets.py): they say "
    "whether each step did its job and never count toward the acceptance verdict."
)
ACCEPTANCE_TITLE = "Acceptance: factory vs commissioned"


def _section(sec: Section, image_prefix: str) -> list[str]:
    out = [f"## {sec.title}", ""]
    if sec.figures:
        out += [*_table(["figure", "value"], [[f.what, f.ours] for f in sec.figures]), ""]
    for t in sec.tables:
        out += _named_table(t)
    if sec.note:
        out += [sec.note, ""]
    return out + [f"![{sec.title}]({image_prefix}{name})\n" for name in sec.all_images()]


def render(report: Report, image_prefix: str = "") -> str:
    """Markdown text; images are linked as `image_prefix` + their name in the build. The first line
    after the title is the headline (the verdict), when the report has one."""
    out = [f"# {report.title}", ""]
    out += [f"**{report.headline}**", ""] if report.headline else []
    out += [report.preamble, ""]
    if report.acceptance:
        out += [f"## {ACCEPTANCE_TITLE}", "", *_table(*verdict_columns(report.acceptance)), ""]
        out += [report.acceptance_note, ""] if report.acceptance_note else []
    for sec in report.acceptance_sections:
        out += _section(sec, image_prefix)
    if report.verdict:  # a report has them; a rendering of sections alone (a test's) does not
        out += [f"## {CHECKS_TITLE}", "", CHECKS_INTRO, "", *_table(*verdict_columns(report.verdict)), ""]
        out += [report.verdict_note, ""] if report.verdict_note else []
    for sec in report.sections:
        out += _section(sec, image_prefix)
    out += ["## Comparison with the paper", "", report.paper_note, ""]
    out += _table(["stage", "figure", "rxcomm", "paper"], report.paper_rows())
    return "\n".join(out) + "\n"


def render_sections(title: str, preamble: str, sections: Sequence[Section]) -> str:
    """Markdown of sections alone (no verdict rows): what a test of one section reads."""
    return render(Report(title, preamble, [], sections))
