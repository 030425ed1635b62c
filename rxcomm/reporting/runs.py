"""The report's sections for planned trajectories (paper §5) and their execution on the drives
(paper §2.3): durations, limit ratios, feed-forward lag, every run.

Pure functions over the summaries of trajectory and run-log artefacts (plain mappings).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rxcomm.reporting.document import (
    DEFAULT_TOLERANCE,
    NOT_MEASURED,
    Figure,
    Section,
    Table,
    Tolerance,
    ratio_note,
)
from rxcomm.reporting.values import fmt
from rxcomm.schemas.run_log import RunLog, RunLogSummary
from rxcomm.schemas.trajectory import TrajectoryFigures

LIMITS = ("position", "velocity", "acceleration", "torque", "torque_rate")


def ran_on(runs: Mapping[str, RunLog]) -> str:
    """What the run logs say they ran on (their `embedded_cell`, the plant in their settings, and
    `gateway`): the simulated cell `run` started itself, per plant where a log names it (older logs
    do not), and/or the gateways by address (a real cell, or a `rxcomm cell-sim` served apart: the
    log cannot tell which)."""
    if not runs:
        return "no cell (no run log in this directory)"
    cells: dict[str, int] = {}
    gateways: dict[str, int] = {}
    for r in runs.values():
        if r.embedded_cell:
            plant = r.settings.plant
            key = "" if plant is None else f", {PLANT_NAMES.get(plant, plant)} plant"
            cells[key] = cells.get(key, 0) + 1
        else:
            gateways[str(r.gateway)] = gateways.get(str(r.gateway), 0) + 1
    n_runs = len(runs)
    parts = [
        f"the simulated cell `run` started itself{k} ({n} of {n_runs} run logs)"
        for k, n in sorted(cells.items())
    ]
    parts += [f"the gateway at {gw} ({n} of {n_runs} run logs)" for gw, n in sorted(gateways.items())]
    return " and ".join(parts)


PLANT_NAMES = {"own": "rxcomm's own", "mujoco": "MuJoCo"}  # the embedded cell's plants (`run --plant`)


def trajectory_section(
    title: str,
    s: TrajectoryFigures,
    image: str | None,
    paper_duration: str,
    tol: Tolerance = DEFAULT_TOLERANCE,
) -> Section:
    per_limit = ", ".join(
        f"{k.replace('_', ' ')} {getattr(s, f'max_{k}_ratio'):.4f}"
        for k in LIMITS
        if getattr(s, f"max_{k}_ratio") is not None
    )
    return Section(
        title,
        [
            Figure("duration", fmt(s.duration_s, digits=4, unit="s"), paper_duration),
            Figure("max limit ratio, sampled at the drive cycle", ratio_note(s.max_limit_ratio, *tol)),
            Figure("max ratio per limit", per_limit or NOT_MEASURED),
            Figure("binding limit", fmt(s.worst_limit)),
            Figure("fraction of time with a limit active", fmt(s.active_fraction), "≈ 1 (time-optimal)"),
            Figure("solve time", fmt(s.solve_seconds, unit="s")),
        ],
        image,
    )


def ptp_vs_cp_figure(cp: TrajectoryFigures, ptp: TrajectoryFigures) -> Figure:
    return Figure(
        "PtP / CP duration between the same end states",
        fmt(ptp.duration_s / cp.duration_s),
        "0.67 s / 1.04 s = 0.64",
    )


def execution_section(ff: RunLogSummary, noff: RunLogSummary | None, image: str | None) -> Section:
    figs = [
        Figure("max joint lag with feed-forward", fmt(ff.max_lag_rad, 1e3, unit="mrad")),
        Figure("max TCP error with feed-forward", fmt(ff.max_tcp_error_m, 1e3, unit="mm")),
        Figure("underruns", fmt(ff.underruns)),
        Figure("min buffered lead while feeding", fmt(ff.min_lead_s, unit="s")),
        Figure("cell cycle overruns", fmt(ff.cell_overruns)),
    ]
    if noff is not None:
        tripped = noff.outcome not in (None, "completed")
        figs += [
            Figure(
                "max joint lag without feed-forward",
                fmt(noff.max_lag_rad, 1e3, unit="mrad")
                + (f" (until the drives tripped: {noff.stop_reason})" if tripped else ""),
            ),
            Figure("max TCP error without feed-forward", fmt(noff.max_tcp_error_m, 1e3, unit="mm")),
            Figure(
                "lag reduction by feed-forward (worst joint)",
                f"{'≥ ' if tripped else ''}×{max(noff.max_lag_rad) / max(ff.max_lag_rad):.1f}",
                "Fig. 2: model-based ≪ standard",
            ),
        ]
    return Section("Execution with model-based feed-forward (paper §2.3, Fig. 2)", figs, image)


def _worst(values: Sequence[float] | None, scale: float) -> str:
    return NOT_MEASURED if not values else f"{max(values) * scale:.3g}"


def runs_section(runs: Mapping[str, RunLog], images: Sequence[str]) -> Section:
    """Every executed run of the build (run log name → its RunLog artefact), one row each."""
    header = ["run log", "feed-forward", "outcome", "duration [s]", "max lag, worst joint [mrad]"]
    header += ["rms lag, worst joint [mrad]", "max TCP error [mm]", "underruns", "min lead [s]"]
    rows = []
    for name, art in runs.items():
        s = art.summary
        rows.append(
            [
                name,
                str(art.feedforward),
                fmt(s.outcome) + (f" ({s.stop_reason})" if s.stop_reason else ""),
                fmt(s.duration_s, digits=4),
                _worst(s.max_lag_rad, 1e3),
                _worst(s.rms_lag_rad, 1e3),
                fmt(s.max_tcp_error_m, 1e3),
                fmt(s.underruns),
                fmt(s.min_lead_s),
            ]
        )
    return Section(
        "Every executed run",
        [Figure("runs executed on the cell", str(len(runs)) if runs else NOT_MEASURED)],
        tables=[Table("", header, rows)] if rows else [],
        images=images,
        note="Lags are following errors q_demand − q_actual; the TCP error is FK of demand vs actual joints "
        "through the nominal model (it cannot see the geometric errors calibration removes).",
    )


# The reference task's runs in each state (the Makefile's names): the time–energy points of the report.
TASK_RUNS = {
    "factory (catalogue timing, no feed-forward)": ("run-factory-cp.yaml", "run-factory-ptp.yaml"),
    "commissioned, time-optimal": ("run-ff.yaml", "run-ptp.yaml"),
    "commissioned, least energy at the factory's cycle time": (
        "run-cp-at-factory-time.yaml",
        "run-ptp-at-factory-time.yaml",
    ),
}


def curve_runs(runs: Mapping[str, RunLog]) -> dict[str, tuple[str, str]]:
    """The time–energy curve's further points (the Makefile's run-cp-curve-X / run-ptp-curve-X), by X."""
    xs = sorted(n[len("run-cp-curve-") : -len(".yaml")] for n in runs if n.startswith("run-cp-curve-"))
    return {
        f"commissioned, least energy at x = {x} of the way to the factory's time": (
            f"run-cp-curve-{x}.yaml",
            f"run-ptp-curve-{x}.yaml",
        )
        for x in xs
    }


def energy_section(runs: Mapping[str, RunLog]) -> Section:
    """The reference task's cycle time and electrical energy (bus, `model.energy`) and ∫τᵀτ in each
    state: the commissioned time–energy points with the factory's beside them (issue 29). A state
    whose runs the build lacks is "not measured"."""
    rows = []
    for what, names in (TASK_RUNS | curve_runs(runs)).items():
        got = [runs[n].summary for n in names if n in runs]
        if len(got) < len(names) or any(g.outcome != "completed" for g in got):
            rows.append([what, NOT_MEASURED, NOT_MEASURED, NOT_MEASURED])
            continue
        t = sum(g.duration_s for g in got)
        e = [g.electrical_energy_j for g in got]
        tau2 = sum(g.tau_squared_integral_nm2_s for g in got)
        rows.append(
            [what, fmt(t, digits=4, unit="s"), fmt(None if None in e else sum(e), digits=4, unit="J"),
             fmt(tau2, digits=4, unit="N²·m²·s")]
        )  # fmt: skip
    note = (
        "The same path and PtP move in each row, CP path then PtP (run logs; the energy drawn from the bus "
        "with copper losses, regeneration as drives.yaml says). The commissioned rows other than the "
        "time-optimal one are planned with the electrical-energy objective (`--objective energy "
        "--duration-s`) at that duration per move: at the factory's, and at T_opt + x·(T_factory − T_opt) "
        "(make's ENERGY_CURVE). The plot: these points as the commissioned time–energy curve, the "
        "factory's point on it; `accept` reads the cycle time at the factory's energy off the curve."
    )
    table = Table(
        "reference task: time–energy points", ["state", "cycle time", "electrical energy", "∫τᵀτ dt"], rows
    )
    images = ["time-energy.png"] if any(n.startswith("run-cp-curve-") for n in runs) else []
    return Section(
        "Energy of the reference task at equal cycle time", [], note=note, tables=[table], images=images
    )
