"""The report's verdict: the headline (`ACCEPTED` / `NOT ACCEPTED — …`) and the acceptance criteria
(`rxcomm accept`'s verdict.yaml: factory, commissioned, ratio, threshold) that make it; then rxcomm's
commissioning checks, one row per stage's headline against a stated target, which never count toward
the verdict.

Inputs are artefact summaries (plain mappings); None is a stage the build lacks, and its row says
"not measured".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from pydantic import Field

from rxcomm.acceptance.verdict import NOT_ACCEPTED, verdict_line
from rxcomm.reporting.document import (
    DEFAULT_TOLERANCE,
    NOT_MEASURED,
    Tolerance,
    Verdict,
    VerdictRow,
    ratio_verdict,
)
from rxcomm.schemas.acceptance import Acceptance
from rxcomm.schemas.calibration import CalibrationSummary
from rxcomm.schemas.dynamics import DynamicsSummary
from rxcomm.schemas.run_log import RunLog, RunLogSummary
from rxcomm.schemas.strict import Strict


class StageTargets(Strict):
    """What each stage must reach. The calibration targets round up the paper's after-calibration
    Table 2 (max 0.41 mm per axis, 0.19°); a fit whose torque prediction explains less than 95 % of the
    validation torque variance is no model for feed-forward; feed-forward must at least halve the lag."""

    heldout_max_position_error_m: float = Field(0.5e-3, gt=0, description="max |e_xyz| on held-out poses, m")
    heldout_max_orientation_error_deg: float = Field(0.2, gt=0, description="max rotation error, degrees")
    validation_r2_min: float = Field(0.95, gt=0, le=1, description="worst scored joint's validation R²")
    lag_reduction_min: float = Field(2.0, gt=1, description="worst-joint max lag without / with feed-forward")


def _at_most(criterion: str, value: float | None, target: float, scale: float, unit: str) -> VerdictRow:
    threshold = f"≤ {target * scale:.3g} {unit}"
    if value is None:
        return VerdictRow(criterion, NOT_MEASURED, threshold, Verdict.not_measured)
    verdict = Verdict.passed if value <= target else Verdict.failed
    note = "" if verdict is Verdict.passed else f"missed by {(value - target) * scale:.3g} {unit}"
    return VerdictRow(criterion, f"{value * scale:.3g} {unit}", threshold, verdict, note)


def calibration_rows(s: CalibrationSummary | None, t: StageTargets) -> list[VerdictRow]:
    ori = None if s is None else s.heldout_max_orientation_error_rad
    return [
        _at_most(
            "calibration: held-out max position error",
            None if s is None else s.heldout_max_position_error_m,
            t.heldout_max_position_error_m,
            1e3,
            "mm",
        ),
        _at_most(
            "calibration: held-out max orientation error",
            None if ori is None else float(np.degrees(ori)),
            t.heldout_max_orientation_error_deg,
            1.0,
            "°",
        ),
    ]


def identification_row(s: DynamicsSummary | None, t: StageTargets) -> VerdictRow:
    criterion, threshold = "identification: validation R², worst moving joint", f"≥ {t.validation_r2_min:g}"
    scored = [r for r in (s.validation_r2 if s else None) or [] if r is not None]
    if not scored:
        return VerdictRow(criterion, NOT_MEASURED, threshold, Verdict.not_measured)
    worst = min(scored)
    ok = worst >= t.validation_r2_min
    n = len(s.validation_r2)
    note = f"{len(scored)} of {n} joints moved on the validation data"
    return VerdictRow(criterion, f"{worst:.4f}", threshold, Verdict.passed if ok else Verdict.failed, note)


def feedforward_row(ff: RunLogSummary | None, noff: RunLogSummary | None, t: StageTargets) -> VerdictRow:
    criterion = "execution: max joint lag without / with feed-forward (worst joint)"
    threshold = f"≥ ×{t.lag_reduction_min:g}"
    if ff is None or noff is None:
        return VerdictRow(criterion, NOT_MEASURED, threshold, Verdict.not_measured)
    with_ff, without = max(ff.max_lag_rad), max(noff.max_lag_rad)
    ratio = without / with_ff
    ok = ratio >= t.lag_reduction_min
    note = f"{without * 1e3:.3g} → {with_ff * 1e3:.3g} mrad"
    value = f"×{ratio:.1f}"
    if noff.outcome not in (None, "completed"):  # tripped: its lag would have grown past the window
        value, note = f"≥ ×{ratio:.1f}", f"{note}; without feed-forward: {noff.stop_reason}"
    return VerdictRow(criterion, value, threshold, Verdict.passed if ok else Verdict.failed, note)


def runs_row(runs: Mapping[str, RunLog]) -> VerdictRow:
    criterion, threshold = "every run completed, no setpoint underrun", "all completed, 0 underruns"
    if not runs:
        return VerdictRow(criterion, NOT_MEASURED, threshold, Verdict.not_measured)
    # a drive trip a run was asked to measure (`run --trip-is-result`: the plan without feed-forward)
    measured = [
        n for n, a in runs.items() if a.summary.outcome == "safety_stop" and a.settings.trip_is_result
    ]
    done = [n for n, a in runs.items() if a.summary.outcome == "completed" or n in measured]
    # a run in virtual time has no deadline to miss: its underruns are a string saying so, not 0
    counted = {n: a.summary.underruns for n, a in runs.items()}
    counted = {n: u for n, u in counted.items() if isinstance(u, int | float)}
    underruns = int(sum(counted.values()))
    ok = len(done) == len(runs) and underruns == 0
    failed = sorted(set(runs) - set(done))
    notes = [f"not completed: {', '.join(failed)}"] if failed else []
    notes += [f"{n}: tripped as its result (--trip-is-result)" for n in measured]
    if counted and len(counted) < len(runs):
        notes.append(f"underruns not applicable (virtual time) in {len(runs) - len(counted)} of {len(runs)}")
    # no run in real time: no deadline, so underruns are not measured (never said as 0)
    counts = f"{underruns} underruns" if counted else "underruns not applicable (virtual time)"
    return VerdictRow(
        criterion,
        f"{len(done)} of {len(runs)} completed, {counts}",
        threshold,
        Verdict.passed if ok else Verdict.failed,
        "; ".join(notes),
    )


def stage_verdicts(
    summaries: Mapping[str, Any],
    runs: Mapping[str, RunLog],
    tolerances: Mapping[str, Tolerance] | None = None,
    targets: StageTargets | None = None,
) -> list[VerdictRow]:
    """Rows for `summaries` keyed calibration, dynamics, excitation, cp, ptp, run-ff, run-noff (None or
    absent: not in the build). `tolerances[key]` is the limit tolerance `run` checked that plan with."""
    t = targets or StageTargets()
    tol = tolerances or {}

    def plan(key: str, what: str) -> VerdictRow:
        s = summaries.get(key)
        ratio = None if s is None else s.max_limit_ratio
        return ratio_verdict(f"{what}: max limit ratio", ratio, *tol.get(key, DEFAULT_TOLERANCE))

    return [
        *calibration_rows(summaries.get("calibration"), t),
        identification_row(summaries.get("dynamics"), t),
        feedforward_row(summaries.get("run-ff"), summaries.get("run-noff"), t),
        plan("excitation", "exciting trajectory"),
        plan("cp", "continuous-path plan"),
        plan("ptp", "point-to-point plan"),
        runs_row(runs),
    ]


def verdict_note(rows: Sequence[VerdictRow], what: str = "criteria") -> str:
    """One sentence under a table: how many rows pass, fail, were not measured."""
    n = {v: sum(r.verdict is v for r in rows) for v in Verdict}
    return (
        f"{n[Verdict.passed]} of {len(rows)} {what} pass, {n[Verdict.failed]} fail, "
        f"{n[Verdict.not_measured]} not measured."
    )


def headline(acceptance: Acceptance | None) -> str:
    """The report's first line: the verdict of an `rxcomm/Acceptance` artefact (plain data) as
    `rxcomm accept` prints it; a build without one is not accepted, and says why."""
    if acceptance is None:
        return f"{NOT_ACCEPTED} — not measured: no verdict.yaml in this build (`rxcomm accept`)"
    return verdict_line([r for r in acceptance.rows])


def _accept_value(x: float | None, unit: str) -> str:
    """A value of the acceptance table: lengths in mm (the ISO 9283 criteria), "not measured" for None."""
    if x is None:
        return NOT_MEASURED
    if unit == "m":
        return f"{x * 1e3:.3g} mm"
    return f"{x:.4g}" + {"1": "", "N2m2s": " N²·m²·s"}.get(unit, f" {unit}")


ACCEPT_VERDICT = {"PASS": Verdict.passed, "FAIL": Verdict.failed, "not measured": Verdict.not_measured}


def acceptance_verdict(acceptance: Acceptance | None) -> list[VerdictRow]:
    """The verdict rows of an `rxcomm/Acceptance` artefact (`rxcomm accept`, plain data): factory,
    commissioned, ratio, threshold per criterion; one "not measured" row when the build has none."""
    if acceptance is None:
        return [
            VerdictRow(
                "acceptance: factory vs commissioned", NOT_MEASURED, "acceptance.yaml", Verdict.not_measured,
                "no verdict.yaml in the build (`rxcomm accept`)",
            )
        ]  # fmt: skip
    out = []
    for r in acceptance.rows:
        bounds = [] if r.max_commissioned is None else [f"≤ {_accept_value(r.max_commissioned, r.unit)}"]
        bounds += [] if r.max_ratio is None else [f"ratio ≤ {r.max_ratio:g}"]
        out.append(
            VerdictRow(
                criterion=r.criterion,
                measured=_accept_value(r.commissioned, r.unit),
                threshold=", ".join(bounds),
                verdict=ACCEPT_VERDICT[r.verdict],
                note=r.note,
                factory=_accept_value(r.factory, r.unit),
                ratio="—" if r.ratio is None else f"{r.ratio:.3g}",
            )
        )
    return out
