"""The report's list of the controller hand-off: the files `make commission` writes to exports/ and the
parity figure each was written with (`rxcomm export --format all`'s parity.yaml)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rxcomm.reporting.document import NOT_MEASURED, Figure, Section, Table

TITLE = "Controller exports (exports/)"


def _figure(row: Mapping[str, Any]) -> tuple[str, str, str]:
    """(reader, max difference, holds) of one export row."""
    p, r = row.get("parity"), row.get("re-read")
    if p:
        diff = f"{p['max_position_m'] * 1e6:.3g} µm / {p['max_orientation_rad'] * 1e6:.3g} µrad"
        holds = "yes" if p["holds_1um"] else f"no: {row.get('note', 'above 1 µm')}"
        return f"{p['reader']}, {p['n_poses']} poses", diff, holds
    if r:
        diff = f"values {r['max_value_difference']:.3g}, times {r['max_time_difference_s']:.3g} s"
        return r["reader"], diff, r["precision"]
    return "", NOT_MEASURED, ""


def exports_section(table: Mapping[str, Any] | None, directory: str = "exports") -> Section:
    """One row per exported file; `table` None (no exports in this build) says not measured."""
    if not table or not table.get("exports"):
        return Section(TITLE, [Figure("controller exports in this build", NOT_MEASURED)])
    rows = [[f"{directory}/{r['file']}", r["format"], r["source"], *_figure(r)] for r in table["exports"]]
    kin = [r for r in table["exports"] if r.get("parity")]
    worst = [r for r in kin if r["format"] in ("urdf", "mdh-hayati", "joint-origins")]
    figures = [Figure("files written", str(len(rows)))]
    if worst:
        m = max(r["parity"]["max_position_m"] for r in worst)
        figures.append(Figure("URDF / Hayati / joint-origin parity, worst", f"{m * 1e6:.3g} µm"))
    plain = [r for r in kin if r["format"] == "mdh"]
    if plain:
        figures.append(Figure("plain MDH residual", f"{plain[0]['parity']['max_position_m'] * 1e3:.3g} mm"))
    header = [
        "file",
        "format",
        "from",
        "read back by",
        "max difference to rxcomm",
        "holds ≤ 1 µm / precision",
    ]
    return Section(
        TITLE,
        figures,
        tables=[Table("", header, rows)],
        note="Each file was read back by a reader that shares no code with rxcomm's kinematics and compared "
        "with the calibrated model's TCP (kinematic files) or with the source samples (trajectories, logs); "
        "docs/logs.md describes every format and its conventions.",
    )
