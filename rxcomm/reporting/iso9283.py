"""The report's ISO 9283 sections, as the standard asks a test report to state them (issue 29):

- the test conditions (load, command speeds, cycles, dwell, measuring window, the tracker and its
  noise) and whether the set run is the standard's or a reduced one;
- the pose test per test pose P1–P5: AP_p, AP_a/b/c, RP_l, RP_a/b/c, in each state;
- the path tests per path and command speed: AT_p, RT_p, AV, RV, and CO where measured, in each state.

Pure functions over `rxcomm/Iso9283` artefacts (plain data: ``iso9283-factory.yaml`` and
``iso9283.yaml``), the run logs they name and the calibration's summary; a state or a value the build
lacks is "not measured", never 0.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from rxcomm.reporting.document import NOT_MEASURED, Section, Table
from rxcomm.schemas.calibration import CalibrationSummary
from rxcomm.schemas.iso9283 import PATHS, POSE_CRITERIA, POSES, Criterion, Iso9283
from rxcomm.schemas.run_log import RunLog

ISO_POSE_CYCLES = 30  # ISO 9283 §7.2.1: 30 cycles of the pose test
ISO_PATH_CYCLES = 10  # §8.2: 10 cycles of each path test
STATES = (("factory", "factory state"), ("commissioned", "commissioned state"))
PATH_KEYS = ("AT_p", "RT_p", "AV", "RV", "CO")


def _value(c: Criterion | None) -> str:
    """One criterion's value in the report's units: mm, degrees (the standard's), % of command speed."""
    if c is None or c.value is None:
        return NOT_MEASURED
    v = float(c.value)
    if c.unit == "m":
        return f"{v * 1e3:.3g} mm"
    if c.unit == "rad":
        return f"{np.degrees(v):.3g}°"
    return f"{v * 100:.3g} %"


def _by(iso: Iso9283 | None) -> dict[tuple[str, str], Criterion]:
    return {} if iso is None else {(c.key, c.target): c for c in iso.criteria}


def pose_table(state: str, iso: Iso9283 | None) -> Table:
    """P1–P5 × (AP_p, AP_a, AP_b, AP_c, RP_l, RP_a, RP_b, RP_c), with the cycles each rests on."""
    by = _by(iso)
    rows = []
    for p in POSES:
        cycles = next((by[k, p].cycles for k in POSE_CRITERIA if (k, p) in by and by[k, p].cycles), None)
        rows.append([p, *(_value(by.get((k, p))) for k in POSE_CRITERIA), str(cycles or NOT_MEASURED)])
    caption = f"pose accuracy and repeatability (ISO 9283 §7.2), {state}"
    return Table(caption, ["pose", *POSE_CRITERIA, "cycles"], rows)


def path_table(state: str, iso: Iso9283 | None) -> Table:
    """One row per test path and command speed: AT_p, RT_p, AV, RV, CO (— where the path has no
    corner), with its command speed and cycles."""
    rows = []
    for target in PATHS:
        crit = [c for c in (iso.criteria if iso else []) if c.target == target]
        speeds = sorted({c.command_speed_m_per_s for c in crit}, key=lambda v: -(v or 0.0))
        for speed in speeds:
            by = {c.key: c for c in crit if c.command_speed_m_per_s == speed}
            first = next(iter(by.values()))
            rows.append(
                [
                    target,
                    NOT_MEASURED if speed is None else f"{speed:.3g} m/s",
                    str(first.cycles or NOT_MEASURED),
                    *("—" if k not in by else _value(by[k]) for k in PATH_KEYS),
                ]
            )
    caption = f"path accuracy, repeatability, velocity and corner overshoot (ISO 9283 §8), {state}"
    return Table(caption, ["path", "command speed", "cycles", *PATH_KEYS], rows)


def _tracker(iso: Iso9283 | None, runs: Mapping[str, RunLog]) -> str:
    """The tracker the state's logs were measured with: source and rate, from the run logs it names."""
    if iso is None:
        return NOT_MEASURED
    names = {n for c in iso.criteria for n in (c.log or "").split(",") if n}
    seen = set()
    for n in sorted(names):
        log = runs.get(n.removesuffix(".mcap") + ".yaml")
        tr = None if log is None else log.tracker
        if tr:
            seen.add(f"{tr.source} at {tr.rate_hz:.4g} Hz")
    return "; ".join(sorted(seen)) or NOT_MEASURED


def _pose_conditions(iso: Iso9283 | None) -> tuple[str, str, str]:
    """(cycles, dwell, measuring window) of a state's pose test."""
    if iso is None:
        return NOT_MEASURED, NOT_MEASURED, NOT_MEASURED
    cycles = [c.cycles for c in iso.criteria if c.target in POSES and c.cycles]
    dwell, window = iso.summary.pose_dwell_s, iso.summary.measuring_window_s
    frac = iso.settings.measure_fraction
    n = NOT_MEASURED if not cycles else f"{min(cycles)} (ISO 9283: {ISO_POSE_CYCLES})"
    d = NOT_MEASURED if not isinstance(dwell, float | int) else f"{dwell:.3g} s"
    w = NOT_MEASURED if not isinstance(window, float | int) else f"{window:.3g} s"
    if frac is not None and w != NOT_MEASURED:
        w += f" (the dwell's last {frac * 100:.0f} %: the mean of the tracker samples there)"
    return n, d, w


def _path_conditions(iso: Iso9283 | None) -> str:
    if iso is None:
        return NOT_MEASURED
    parts = [
        f"{c.target} {c.command_speed_m_per_s:.3g} m/s × {c.cycles}"
        for c in iso.criteria
        if c.target in PATHS and c.key == "AT_p" and c.value is not None
    ]
    return "; ".join(parts) or NOT_MEASURED


def reduced(isos: Sequence[Iso9283 | None]) -> str:
    """Which test set this is: the standard's counts, or what a reduced chain left out."""
    cycles = [c.cycles for iso in isos if iso for c in iso.criteria if c.cycles and c.value is not None]
    pose = [c.cycles for iso in isos if iso for c in iso.criteria if c.target in POSES and c.cycles]
    path = [c.cycles for iso in isos if iso for c in iso.criteria if c.target in PATHS and c.cycles]
    if not cycles:
        return "no ISO 9283 test in this build"
    short = []
    if pose and min(pose) < ISO_POSE_CYCLES:
        short.append(f"{min(pose)} pose cycles instead of {ISO_POSE_CYCLES}")
    if path and min(path) < ISO_PATH_CYCLES:
        short.append(f"{min(path)} path cycles instead of {ISO_PATH_CYCLES}")
    per_path: dict[str, set] = {}
    for iso in isos:
        for c in iso.criteria if iso else []:
            if c.target in PATHS and c.key == "AT_p" and c.value is not None:
                per_path.setdefault(c.target, set()).add(c.command_speed_m_per_s)
    if any(len(v) < 3 for v in per_path.values()):
        one = sorted(t for t, v in per_path.items() if len(v) < 3)
        short.append(
            f"{', '.join(one)} at fewer than 3 command speeds (ISO 9283: 100, 50 and 10 % of the rated)"
        )
    missing = sorted(set(PATHS) - set(per_path))
    if missing:
        short.append(f"not run: {', '.join(missing)}")
    short.append("no payload (ISO 9283: 100 % and 10 % of the rated load)")
    return "reduced set: " + "; ".join(short)


def conditions_table(
    factory: Iso9283 | None,
    commissioned: Iso9283 | None,
    runs: Mapping[str, RunLog],
    cal: CalibrationSummary | None,
) -> Table:
    """The test conditions ISO 9283 asks a report to state, per state."""
    f_pose, c_pose = _pose_conditions(factory), _pose_conditions(commissioned)
    sigma = None if cal is None else cal.tracker_position_sigma_m
    noise = NOT_MEASURED if sigma is None else f"{sigma * 1e6:.3g} µm per axis (1σ, the calibration's)"
    load = "none mounted: 0 % of the rated load (the simulated cell carries no payload)"
    rows = [
        ["load", load, load],
        ["pose test: cycles", f_pose[0], c_pose[0]],
        ["pose test: dwell at each pose", f_pose[1], c_pose[1]],
        ["pose test: measuring window", f_pose[2], c_pose[2]],
        ["path tests: command speed × cycles", _path_conditions(factory), _path_conditions(commissioned)],
        [
            "speed as % of the rated speed",
            "not stated: drives.yaml gives no rated TCP speed",
            "not stated: drives.yaml gives no rated TCP speed",
        ],
        ["tracker", _tracker(factory, runs), _tracker(commissioned, runs)],
        ["tracker noise", noise, noise],
    ]
    return Table("test conditions (ISO 9283 §6)", ["condition", "factory", "commissioned"], rows)


def iso9283_sections(
    factory: Iso9283 | None,
    commissioned: Iso9283 | None,
    runs: Mapping[str, RunLog] | None = None,
    calibration_summary: CalibrationSummary | None = None,
) -> list[Section]:
    """The ISO 9283 section of the report: conditions, then the pose and path tables of each state."""
    tables = [conditions_table(factory, commissioned, runs or {}, calibration_summary)]
    for state, text in STATES:
        iso = factory if state == "factory" else commissioned
        tables += [pose_table(text, iso), path_table(text, iso)]
    note = (
        reduced([factory, commissioned])
        + ". AP_a/b/c: mean attained minus command orientation about the base x, y, z axes; RP_a/b/c: 3 S; "
        "AV, RV in % of the command speed. Only the worst values are acceptance criteria (acceptance.yaml)."
    )
    return [Section("ISO 9283 performance criteria, per pose and per path", [], note=note, tables=tables)]
