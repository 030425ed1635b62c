"""The report's ISO 9283 sections, as the standard asks a test report to state them (issue 29):

- the test conditions (load, command speeds, cycles, dwell, measuring window, the tracker and its
  noise) and whether the set run is the standard's or a reduced one;
- one such block per test set: a build runs its ISO 9283 tests at one load (``iso9283.yaml``,
  ``iso9283-factory.yaml``) and, `make acceptance`, again at further loads (``iso9283-load-L.yaml``);
  a set's load is the identified payload the commissioned runs fed forward (their envelope's
  ``payload`` input, matched to the build's ``payload-L.yaml`` by sha256: L % of the rated load);
- the pose test per test pose P1–P5: AP_p, AP_a/b/c, RP_l, RP_a/b/c, in each state;
- the path tests per path and command speed: AT_p, RT_p, AV, RV, and CO where measured, in each state.

Pure functions over `rxcomm/Iso9283` artefacts (plain data: ``iso9283-factory.yaml`` and
``iso9283.yaml``), the run logs they name and the calibration's summary; a state or a value the build
lacks is "not measured", never 0.
"""

from __future__ import annotations

import re
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from rxcomm.reporting.document import NOT_MEASURED, Section, Table
from rxcomm.schemas.calibration import CalibrationSummary
from rxcomm.schemas.iso9283 import PATHS, POSE_CRITERIA, POSES, Criterion, Iso9283
from rxcomm.schemas.payload import Payload
from rxcomm.schemas.run_log import RunLog

ISO_POSE_CYCLES = 30  # ISO 9283 §7.2.1: 30 cycles of the pose test
ISO_PATH_CYCLES = 10  # §8.2: 10 cycles of each path test
STATES = (("factory", "factory state"), ("commissioned", "commissioned state"))
PATH_KEYS = ("AT_p", "RT_p", "AV", "RV", "CO")
NO_LOAD = (
    "none mounted: 0 % of the rated load (no payload in the commissioned runs' feed-forward; "
    "`make commission` mounts none, `make acceptance` tests at 100 % and 10 %)"
)


@dataclass(frozen=True)
class TestSet:
    """One ISO 9283 test set: both states' criteria at one load."""

    factory: Iso9283 | None
    commissioned: Iso9283 | None
    payloads: Mapping[str, tuple[str, Payload]] = field(default_factory=dict)  # name -> (sha256, artefact)


def rated_percent(name: str) -> int | None:
    """L of a payload-L.yaml (the Makefile's LOAD / LOADS_EXTRA: L % of the rated load), else None."""
    m = re.fullmatch(r"payload-(\d+)\.yaml", name)
    return None if m is None else int(m.group(1))


def _logs(iso: Iso9283 | None, runs: Mapping[str, RunLog]) -> list[RunLog]:
    names = sorted({n for c in (iso.criteria if iso else []) for n in (c.log or "").split(",") if n})
    return [log for n in names if (log := runs.get(n.removesuffix(".mcap") + ".yaml")) is not None]


def set_payload(ts: TestSet, runs: Mapping[str, RunLog]) -> tuple[str, Payload] | None | str:
    """The identified payload the set's commissioned runs fed forward: (file name, artefact); None: none
    of them took one; a string: what is wrong (runs disagreeing, a payload not in the build)."""
    shas = {log.inputs.get("payload") for log in _logs(ts.commissioned, runs)}
    if not shas or shas == {None}:
        return None
    if len(shas) > 1:
        return "not stated: the set's commissioned runs fed forward different payloads"
    (sha,) = shas
    found = [(n, art) for n, (h, art) in ts.payloads.items() if h == sha]
    return found[0] if found else "not stated: the runs' payload file is not in this build"


def set_label(ts: TestSet, runs: Mapping[str, RunLog]) -> str:
    """How the report names a set: by its load ("" without a payload)."""
    got = set_payload(ts, runs)
    if not isinstance(got, tuple):
        return "" if got is None else "at a load not stated"
    pct = rated_percent(got[0])
    return f"at {got[0]}" if pct is None else f"at {pct} % of the rated load"


def load_condition(ts: TestSet, runs: Mapping[str, RunLog]) -> str:
    """The load row of a set's test conditions: the identified payload and the % of the rated load."""
    got = set_payload(ts, runs)
    if got is None:
        return NO_LOAD
    if isinstance(got, str):
        return got
    name, art = got
    pct = rated_percent(name)
    com = ", ".join(f"{v * 1e3:.1f}" for v in art.com_m)
    share = NOT_MEASURED if pct is None else f"{pct} % of the rated load"
    return (
        f"{share}: {name}, identified {art.mass_kg:.3f} ± {art.mass_std_kg:.3f} kg, centre of mass "
        f"({com}) mm in the flange frame; fed forward in the commissioned plans and runs, carried "
        "without a model in the factory state"
    )


def payload_table(payloads: Mapping[str, tuple[str, Payload]]) -> Table:
    """The loads identify-payload identified for the tests (mass, centre of mass ± σ, validation)."""
    rows = []
    for name, (_, art) in sorted(payloads.items(), key=lambda kv: -(rated_percent(kv[0]) or 0)):
        pct = rated_percent(name)
        com = ", ".join(
            f"{c * 1e3:.2f} ± {s * 1e3:.2f}" for c, s in zip(art.com_m, art.com_std_m, strict=True)
        )
        val = art.validation
        rms = (
            NOT_MEASURED
            if val is None
            else f"{val.total_rms_without_nm:.3g} → {val.total_rms_with_nm:.3g} N·m ({val.log})"
        )
        rows.append(
            [
                name,
                NOT_MEASURED if pct is None else f"{pct} %",
                f"{art.mass_kg:.4f} ± {art.mass_std_kg:.4f} kg",
                f"({com}) mm",
                rms,
            ]
        )
    caption = "test loads identified by `identify-payload` (robot model held fixed)"
    header = [
        "payload",
        "of the rated load",
        "mass",
        "centre of mass (flange)",
        "validation RMS without → with",
    ]
    return Table(caption, header, rows)


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


def reduced(isos: Sequence[Iso9283 | None], loads_pct: Collection[int] = ()) -> str:
    """Which test set this is: the standard's counts, or what a reduced chain left out (`loads_pct`: the
    % of the rated load of the sets run; none: no payload)."""
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
    if not loads_pct:
        short.append("no payload (ISO 9283: 100 % and 10 % of the rated load; `make acceptance` runs them)")
    else:
        short += [f"not at {p} % of the rated load" for p in (100, 10) if p not in loads_pct]
    return "reduced set: " + "; ".join(short) if short else "the standard's counts"


def conditions_table(ts: TestSet, runs: Mapping[str, RunLog], cal: CalibrationSummary | None) -> Table:
    """The test conditions ISO 9283 asks a report to state, per state, of one test set."""
    factory, commissioned = ts.factory, ts.commissioned
    f_pose, c_pose = _pose_conditions(factory), _pose_conditions(commissioned)
    sigma = None if cal is None else cal.tracker_position_sigma_m
    noise = NOT_MEASURED if sigma is None else f"{sigma * 1e6:.3g} µm per axis (1σ, the calibration's)"
    load = load_condition(ts, runs)
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
    label = set_label(ts, runs)
    caption = "test conditions (ISO 9283 §6)" + (f", {label}" if label else "")
    return Table(caption, ["condition", "factory", "commissioned"], rows)


def iso9283_sections(
    sets: Sequence[TestSet],
    runs: Mapping[str, RunLog] | None = None,
    calibration_summary: CalibrationSummary | None = None,
) -> list[Section]:
    """The ISO 9283 section of the report: per test set (load), its conditions, then the pose and path
    tables of each state; the identified test loads."""
    runs = runs or {}
    tables, loads = [], set()
    for ts in sets:
        tables.append(conditions_table(ts, runs, calibration_summary))
        label = set_label(ts, runs)
        for state, text in STATES:
            iso = ts.factory if state == "factory" else ts.commissioned
            text = f"{text}, {label}" if label else text
            tables += [pose_table(text, iso), path_table(text, iso)]
        got = set_payload(ts, runs)
        if isinstance(got, tuple) and (pct := rated_percent(got[0])) is not None:
            loads.add(pct)
    payloads = {n: p for ts in sets for n, p in ts.payloads.items()}
    if payloads:
        tables.append(payload_table(payloads))
    isos = [iso for ts in sets for iso in (ts.factory, ts.commissioned)]
    label = set_label(sets[0], runs) if sets else ""
    main = f"The acceptance criteria read the set {label}. " if label and len(sets) > 1 else ""
    note = (
        reduced(isos, loads)
        + f". {main}AP_a/b/c: mean attained minus command orientation about the base x, y, z axes; "
        "RP_a/b/c: 3 S; AV, RV in % of the command speed. Only the worst values are acceptance criteria "
        "(acceptance.yaml)."
    )
    images = [f"{n.removesuffix('.yaml')}.png" for n in sorted(payloads)]
    return [
        Section(
            "ISO 9283 performance criteria, per pose and per path",
            [],
            note=note,
            tables=tables,
            images=images,
        )
    ]
