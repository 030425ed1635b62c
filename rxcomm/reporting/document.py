"""The report's document model: what both renderings (Markdown, HTML) draw, in reading order.

A report opens with its headline, one line: ``ACCEPTED`` or ``NOT ACCEPTED — n of m acceptance criteria
failed: …``; then the acceptance table (factory vs commissioned, the criteria that make the verdict)
and the sections that detail it (ISO 9283 as the standard writes it); then rxcomm's own commissioning
checks (criterion, measured, threshold, verdict), which never count toward the verdict; then one
section per stage (headline figures, parameter tables, images), then the paper comparison, built from
every figure that carries a paper value, so a stage section reads as a result and not as a comparison.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import StrEnum

NOT_MEASURED = "not measured"

Tolerance = tuple[float, str]  # a limit ratio's relative tolerance, and where it comes from
# When no run log states the tolerance `run` checked a plan against: `run`'s default limit_tolerance.
DEFAULT_TOLERANCE: Tolerance = (2e-3, "the default limit_tolerance of `run`")  # model.limits'


@dataclass(frozen=True)
class Figure:
    """One headline number: ours, the paper's (shown in the paper comparison), and what it answers."""

    what: str
    ours: str
    paper: str = ""


@dataclass(frozen=True)
class Table:
    """A table of strings: parameters ± σ, per-axis errors, the runs."""

    caption: str
    header: Sequence[str]
    rows: Sequence[Sequence[str]]


@dataclass(frozen=True)
class Section:
    """One stage's results. `image` (a file name in the build) is drawn after the tables."""

    title: str
    figures: Sequence[Figure]
    image: str | None = None
    note: str = ""
    tables: Sequence[Table] = ()
    images: Sequence[str] = ()

    def all_images(self) -> list[str]:
        return ([self.image] if self.image else []) + list(self.images)


class Verdict(StrEnum):
    passed = "pass"
    failed = "fail"
    not_measured = NOT_MEASURED


@dataclass(frozen=True)
class VerdictRow:
    """One acceptance criterion. `factory` and `ratio` (factory vs commissioned state) are left empty
    when the build measured one state only; the renderings drop a column no row fills."""

    criterion: str
    measured: str
    threshold: str
    verdict: Verdict
    note: str = ""
    factory: str = ""
    ratio: str = ""


@dataclass(frozen=True)
class Report:
    """`verdict`: rxcomm's commissioning checks (stage targets; never the verdict); `headline` and
    `acceptance`: the verdict line and the acceptance criteria it counts, `acceptance_sections` the
    detail under them (the ISO 9283 tables)."""

    title: str
    preamble: str
    verdict: Sequence[VerdictRow]
    sections: Sequence[Section]
    verdict_note: str = ""
    headline: str = ""
    acceptance: Sequence[VerdictRow] = ()
    acceptance_note: str = ""
    acceptance_sections: Sequence[Section] = ()
    paper_note: str = field(
        default="The reference paper's figures are the Stäubli RX130L's, measured on the real robot; "
        "ours are this build's. They answer the same question, not under the same conditions."
    )

    def paper_rows(self) -> list[tuple[str, str, str, str]]:
        """(section, figure, ours, paper) for every figure with a paper value, in report order."""
        return [(s.title, f.what, f.ours, f.paper) for s in self.sections for f in s.figures if f.paper]


def ratio_verdict(criterion: str, ratio: float | None, tolerance: float, tolerance_source: str) -> VerdictRow:
    """A limit ratio against ≤ 1: above 1 but within `tolerance` (the one `run` checks plans against)
    passes with a note that says so (a solver's accuracy, not a violation); beyond it fails, by how much."""
    threshold = "≤ 1"
    if ratio is None:
        return VerdictRow(criterion, NOT_MEASURED, threshold, Verdict.not_measured)
    text = f"{ratio:.4f}"
    if ratio <= 1.0:
        return VerdictRow(criterion, text, threshold, Verdict.passed)
    over = f"{(ratio - 1.0) * 100:.2g} % above the limit"
    bound = f"tolerance of {tolerance * 100:.2g} % ({tolerance_source})"
    if ratio <= 1.0 + tolerance:
        note = f"{over}: within the {bound}, solver accuracy, not a violation"
        return VerdictRow(criterion, text, threshold, Verdict.passed, note)
    return VerdictRow(criterion, text, threshold, Verdict.failed, f"{over}: a violation, beyond the {bound}")


def ratio_note(ratio: float | None, tolerance: float, tolerance_source: str) -> str:
    """The figure text of a limit ratio, flagged when above 1 (see `ratio_verdict`)."""
    row = ratio_verdict("", ratio, tolerance, tolerance_source)
    return row.measured + (f" ({row.note})" if row.note else "")


def missing_section(title: str, names: Sequence[str]) -> Section:
    """A stage whose artefacts this build lacks: its figures are not measured, said so."""
    return Section(title, [Figure(f"{', '.join(names)} in this build", NOT_MEASURED)])
