"""The acceptance verdict: factory vs commissioned, criterion by criterion (issue 17).

Pure functions over what the stages measured: the ISO 9283 criteria of each state
(`rxcomm.schemas.iso9283.Iso9283`, from the tracker) and the run-log summaries of each state's
reference task (its cycle time and energy figures, `rxcomm.execution.summary.run_summary`). A value that
was not measured stays None and its verdict is "not measured", never PASS and never a zero.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from rxcomm.schemas.acceptance import TASK_CRITERIA, Threshold, VerdictRow
from rxcomm.schemas.iso9283 import Iso9283
from rxcomm.schemas.run_log import RunLogSummary

SPEED_TOLERANCE = 0.05  # an ISO path criterion matches a threshold's command speed within ±5 %
TASK_SUMMARY_KEYS = {
    "cycle_time": "duration_s",
    "tau_squared_integral": "tau_squared_integral_nm2_s",
    "electrical_energy": "electrical_energy_j",
    "electrical_energy_at_factory_time": "electrical_energy_j",
}
EQUAL_TIME_TOLERANCE = 0.02  # the equal-time runs' cycle time within 2 % of the factory's


@dataclass(frozen=True)
class Measured:
    """A value (None: not measured) and what it rests on or why it is missing."""

    value: float | None
    note: str = ""


def task_value(criterion: str, runs: Sequence[RunLogSummary]) -> Measured:
    """A reference-task figure: the sum over its runs' summaries (a missing or null figure in any
    run, or no run at all, is not measured; a run that did not complete is not measured either)."""
    if not runs:
        return Measured(None, "no run log of the reference task")
    key = TASK_SUMMARY_KEYS[criterion]
    total = 0.0
    for i, s in enumerate(runs):
        if (s.outcome or "completed") != "completed":
            return Measured(None, f"run {i + 1} ended {s.outcome!r}")
        v = getattr(s, key)
        if v is None:
            return Measured(None, f"run {i + 1} has no {key}")
        total += float(v)
    return Measured(total, f"sum of {len(runs)} run(s)")


def iso_value(threshold: Threshold, iso: Iso9283 | None) -> Measured:
    """The worst |value| of the ISO criterion over the matching targets (and command speed)."""
    if iso is None:
        return Measured(None, "no ISO 9283 measurement of this state")
    rows = [c for c in iso.criteria if c.key == threshold.criterion]
    if threshold.target is not None:
        rows = [c for c in rows if c.target == threshold.target]
    v_cmd = threshold.command_speed_m_per_s
    if v_cmd is not None:
        speeds = sorted({c.command_speed_m_per_s for c in rows if c.command_speed_m_per_s is not None})
        near = [
            c
            for c in rows
            if c.command_speed_m_per_s is not None
            and abs(c.command_speed_m_per_s - v_cmd) <= SPEED_TOLERANCE * v_cmd
        ]
        if speeds and not near:
            at = ", ".join(f"{v:.3g}" for v in speeds)
            return Measured(None, f"measured at a command speed of {at} m/s only, not {v_cmd:g} m/s")
        rows = near or rows  # no speed at all: every row is unmeasured, and says why below
    if not rows:
        return Measured(None, "not in the ISO 9283 artefact")
    measured = [c for c in rows if c.value is not None]
    if len(measured) < len(rows):
        missing = [c for c in rows if c.value is None]
        return Measured(None, f"{missing[0].target}: {missing[0].note or 'not measured'}")
    worst = max(measured, key=lambda c: abs(c.value))
    cycles = f", {worst.cycles} cycle{'s' if worst.cycles != 1 else ''}" if worst.cycles else ""
    said = f"; {worst.note}" if worst.note else ""  # e.g. how settled the arm was where it was worst
    return Measured(abs(worst.value), f"worst of {len(rows)}: {worst.target}{cycles}{said}")


def label(t: Threshold) -> str:
    out = t.criterion + (f" {t.target}" if t.target else "")
    if t.command_speed_m_per_s is not None:
        out += f" at {t.command_speed_m_per_s:g} m/s"
    return out


def threshold_text(t: Threshold) -> str:
    parts = []
    if t.max_commissioned is not None:
        parts.append(f"≤ {t.max_commissioned:g} {t.unit}")
    if t.max_ratio is not None:
        parts.append(f"ratio ≤ {t.max_ratio:g}")
    return ", ".join(parts)


def verdict_row(t: Threshold, factory: Measured, commissioned: Measured) -> VerdictRow:
    """PASS when every bound the threshold sets holds, FAIL when one does not, "not measured" when a
    value a bound needs is missing (the ratio needs both states)."""
    f, c = factory.value, commissioned.value
    ratio = abs(c) / abs(f) if f is not None and c is not None and f != 0 else None
    missing = []
    if c is None:
        missing.append(f"commissioned: {commissioned.note}")
    if t.max_ratio is not None and f is None:
        missing.append(f"factory: {factory.note}")
    elif t.max_ratio is not None and f == 0:
        missing.append("factory value is 0")
    if len(missing) == 2 and f is None and factory.note == commissioned.note:
        missing = [f"both states: {factory.note}"]
    if missing:
        verdict = "not measured"
    else:
        ok = (t.max_commissioned is None or abs(c) <= t.max_commissioned) and (
            t.max_ratio is None or ratio <= t.max_ratio
        )
        verdict = "PASS" if ok else "FAIL"
    note = "; ".join(missing) if missing else commissioned.note
    if f is None and not any(m.startswith(("factory", "both")) for m in missing):
        note += f"; factory: {factory.note}"  # e.g. it could not run at the command speed
    return VerdictRow(
        criterion=label(t),
        unit=t.unit,
        factory=f,
        commissioned=c,
        ratio=ratio,
        threshold=threshold_text(t),
        max_commissioned=t.max_commissioned,
        max_ratio=t.max_ratio,
        verdict=verdict,
        note=note,
    )


def equal_time_value(
    factory_runs: Sequence[RunLogSummary], equal_time_runs: Sequence[RunLogSummary]
) -> Measured:
    """The commissioned task's electrical energy at the factory's cycle time: the sum over its
    slowed runs, "not measured" when there are none or their cycle time is not the factory's."""
    if not equal_time_runs:
        return Measured(None, "no run of the commissioned task at the factory's cycle time")
    t_f = task_value("cycle_time", factory_runs)
    t_c = task_value("cycle_time", equal_time_runs)
    if t_f.value is None or t_c.value is None:
        return Measured(None, t_f.note if t_f.value is None else t_c.note)
    if abs(t_c.value - t_f.value) > EQUAL_TIME_TOLERANCE * t_f.value:
        return Measured(None, f"run at {t_c.value:.4g} s, not the factory's {t_f.value:.4g} s")
    e = task_value("electrical_energy_at_factory_time", equal_time_runs)
    return Measured(e.value, f"{e.note} at {t_c.value:.4g} s (factory {t_f.value:.4g} s)")


def time_energy_points(tasks: Sequence[Sequence[RunLogSummary]]) -> list[tuple[float, float]]:
    """(cycle time, electrical energy) of each measured task (its runs' sums), by cycle time; tasks
    with a figure not measured are left out."""
    pts = []
    for runs in tasks:
        t, e = task_value("cycle_time", runs).value, task_value("electrical_energy", runs).value
        if t is not None and e is not None:
            pts.append((t, e))
    return sorted(pts)


def time_at_energy(points: Sequence[tuple[float, float]], energy_j: float | None) -> Measured:
    """The shortest cycle time at which the time–energy curve (piecewise linear between the measured
    points) needs no more than `energy_j`: the fastest point if it already does, "not measured" if no
    measured point does (the curve is not known beyond its slowest point)."""
    if energy_j is None:
        return Measured(None, "the factory's energy is not measured")
    if not points:
        return Measured(None, "no measured point of the commissioned time–energy curve")
    n = f"{len(points)} measured points"
    if points[0][1] <= energy_j:
        return Measured(points[0][0], f"the fastest of {n} already needs ≤ the factory's energy")
    for (t0, e0), (t1, e1) in zip(points, points[1:], strict=False):
        if e1 <= energy_j:
            return Measured(t0 + (e0 - energy_j) / (e0 - e1) * (t1 - t0), f"interpolated between {n}")
    t_max, e_max = points[-1]
    return Measured(None, f"every one of {n} needs more (slowest: {e_max:.4g} J at {t_max:.4g} s)")


def acceptance_rows(
    thresholds: Sequence[Threshold],
    factory_runs: Sequence[RunLogSummary],
    commissioned_runs: Sequence[RunLogSummary],
    factory_iso: Iso9283 | None,
    commissioned_iso: Iso9283 | None,
    equal_time_runs: Sequence[RunLogSummary] = (),
    curve_tasks: Sequence[Sequence[RunLogSummary]] = (),
) -> list[VerdictRow]:
    """One verdict row per threshold, in the thresholds' order. `equal_time_runs`: the commissioned
    reference task at the factory's cycle time (electrical_energy_at_factory_time); `curve_tasks`:
    the runs of further commissioned tasks at other cycle times (cycle_time_at_factory_energy, with the
    time-optimal and the equal-time task)."""
    rows = []
    for t in thresholds:
        if t.criterion == "electrical_energy_at_factory_time":
            f = task_value("electrical_energy", factory_runs)
            c = equal_time_value(factory_runs, equal_time_runs)
        elif t.criterion == "cycle_time_at_factory_energy":
            f = task_value("cycle_time", factory_runs)
            points = time_energy_points([commissioned_runs, equal_time_runs, *curve_tasks])
            c = time_at_energy(points, task_value("electrical_energy", factory_runs).value)
        elif t.criterion in TASK_CRITERIA:
            f, c = task_value(t.criterion, factory_runs), task_value(t.criterion, commissioned_runs)
        else:
            f, c = iso_value(t, factory_iso), iso_value(t, commissioned_iso)
        rows.append(verdict_row(t, f, c))
    return rows


ACCEPTED = "ACCEPTED"
NOT_ACCEPTED = "NOT ACCEPTED"


def verdict_line(rows: Sequence[VerdictRow]) -> str:
    """The one line a report and `accept`'s console open with: ``ACCEPTED`` when every acceptance
    criterion passes, else ``NOT ACCEPTED — n of m acceptance criteria failed: …`` naming the failed
    ones (and the unmeasured ones, which cannot accept a robot either)."""
    failed = [r.criterion for r in rows if r.verdict == "FAIL"]
    unmeasured = [r.criterion for r in rows if r.verdict == "not measured"]
    if not rows:
        return f"{NOT_ACCEPTED} — no acceptance criterion was judged"
    if not failed and not unmeasured:
        return ACCEPTED
    line = f"{NOT_ACCEPTED} — {len(failed)} of {len(rows)} acceptance criteria failed"
    line += f": {', '.join(failed)}" if failed else ""
    if unmeasured:
        line += f"; {len(unmeasured)} not measured: {', '.join(unmeasured)}"
    return line


def overall(rows: Sequence[VerdictRow]) -> dict[str, object]:
    """The summary: FAIL if any row fails, PASS if all pass, else incomplete (some not measured);
    `accepted` (true only when all pass) and the verdict line make and CI gate on."""
    n_pass = sum(r.verdict == "PASS" for r in rows)
    n_fail = sum(r.verdict == "FAIL" for r in rows)
    n_nm = len(rows) - n_pass - n_fail
    verdict = "FAIL" if n_fail else ("PASS" if n_nm == 0 and rows else "incomplete")
    return {
        "verdict": verdict,
        "accepted": verdict == "PASS",
        "verdict_line": verdict_line(rows),
        "n_criteria": len(rows),
        "n_pass": n_pass,
        "n_fail": n_fail,
        "n_not_measured": n_nm,
    }
