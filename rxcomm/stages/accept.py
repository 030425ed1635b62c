"""`rxcomm accept`: the verdict of the commissioning, factory vs commissioned (issue 17).

Reads the acceptance thresholds (``samples/ROBOT/acceptance.yaml``, kind `rxcomm/AcceptanceThresholds`),
the run logs of the reference task in each state (``--factory-log``, ``--commissioned-log``, repeated:
their ``NAME.yaml`` summaries give cycle time and energy) and optionally each state's ISO 9283
criteria (``--factory-iso9283``, ``--commissioned-iso9283``, kind `rxcomm/Iso9283`), and writes
``verdict.yaml`` (kind `rxcomm/Acceptance`): criterion, factory, commissioned, ratio, threshold,
verdict. Anything not given is "not measured", and the summary's verdict is then "incomplete".

The console opens with one line, ``ACCEPTED`` or ``NOT ACCEPTED — n of m acceptance criteria failed:
…`` (`rxcomm.acceptance.verdict.verdict_line`); the exit code is 0 either way (a verdict is a result,
not an error): make and CI gate on the summary's ``accepted``.

``--plot`` writes ``time-energy.png`` beside the verdict: the commissioned time–energy curve (its
measured points: time-optimal, ``--commissioned-curve-log`` groups, the factory's cycle time) with the
factory's point on it (issue 29).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.files import check_outputs, mcap_summary_path
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model, write_yaml_artefact
from rxcomm.schemas.acceptance import Acceptance, AcceptanceSummary, AcceptanceThresholds
from rxcomm.schemas.iso9283 import Iso9283
from rxcomm.schemas.run_log import RunLog, RunLogSummary


def _summary_file(log: Path) -> Path:
    """A run log is named by its MCAP or its summary YAML; the summary is what is read."""
    return mcap_summary_path(log) if log.suffix == ".mcap" else log


def print_verdict(summary: AcceptanceSummary, rows) -> None:
    """The verdict first, one line (make and CI gate on summary.accepted; the exit code is 0 either
    way), then the criteria, factory → commissioned."""
    console.out.print(summary.verdict_line, markup=False, highlight=False)
    console.out.print("acceptance criteria, factory → commissioned:")
    for r in rows:
        ratio = "—" if r.ratio is None else f"{r.ratio:.3g}"
        f = "not measured" if r.factory is None else f"{r.factory:.4g}"
        c = "not measured" if r.commissioned is None else f"{r.commissioned:.4g}"
        console.out.print(
            f"  {r.criterion:32s} {f:>13s} → {c:>13s} {r.unit:5s} ratio {ratio:>6s}  "
            f"{r.threshold:18s} {r.verdict}",
            markup=False,
            highlight=False,
        )


SAME_TASK_RAD = 0.05  # end states of one task in both states: the calibration moves them by mrad


def check_same_task(f_files: list[Path], c_files: list[Path]) -> None:
    """Each factory / commissioned pair executed the same task: two different logs whose first and
    last setpoints agree within ``SAME_TASK_RAD`` per joint (the calibration and the compliance
    compensation move them by milliradians; another task by far more). InputError otherwise."""
    from rxcomm.io.run_log import read_run_log
    from rxcomm.schemas.plain import sha256_file

    for i, (f, c) in enumerate(zip(f_files, c_files, strict=True)):
        if sha256_file(f) == sha256_file(c):
            raise InputError(
                f"factory log {i + 1} is the same run log as commissioned log {i + 1} ({f.name}): compare "
                "the factory run with the commissioned run of the same task",
                file=c,
                field="commissioned-log",
            )
        mcaps = [p.with_name(read_yaml_artefact(p, RunLog).mcap_file) for p in (f, c)]
        if not all(m.is_file() for m in mcaps):
            console.err.print(
                f"warning: pair {i + 1}: end states not compared (no MCAP beside {f.name} / {c.name})"
            )
            continue
        ends = []
        for p, mcap in zip((f, c), mcaps, strict=True):
            q = read_run_log(mcap, fields=("q_demand",)).joints["q_demand"]
            if len(q) == 0:
                raise InputError("the run log holds no setpoints", file=p, field="n_records")
            ends.append((q[0], q[-1]))
        gap = max(float(abs(a - b).max()) for a, b in zip(ends[0], ends[1], strict=True))
        if gap > SAME_TASK_RAD:
            raise InputError(
                f"factory log {f.name} and commissioned log {c.name} did not execute the same task: their "
                f"start or end setpoints differ by up to {gap:.3f} rad (> {SAME_TASK_RAD} rad)",
                file=c,
                field="commissioned-log",
            )


@console.stage_command
def command(
    thresholds: Annotated[
        Path,
        typer.Option("--thresholds", help="acceptance.yaml beside the cell (rxcomm/AcceptanceThresholds)."),
    ],
    output: Annotated[
        Path, typer.Option("-o", "--output", help="verdict.yaml to write (rxcomm/Acceptance).")
    ],
    factory_log: Annotated[
        list[Path] | None,
        typer.Option(help="Run log (NAME.mcap or NAME.yaml) of the reference task, factory state; repeat."),
    ] = None,
    commissioned_log: Annotated[
        list[Path] | None,
        typer.Option(help="Run log of the reference task, commissioned state; repeat, same moves."),
    ] = None,
    commissioned_equal_time_log: Annotated[
        list[Path] | None,
        typer.Option(
            help="Run log of the commissioned reference task at the factory's cycle time (plan-cp/plan-ptp "
            "--objective energy --duration-s); repeat, same moves: the energy at equal time."
        ),
    ] = None,
    commissioned_curve_log: Annotated[
        list[Path] | None,
        typer.Option(
            help="Run logs of the commissioned task at further cycle times (the time–energy curve), in "
            "groups of the task's moves (as many as --commissioned-log); repeat."
        ),
    ] = None,
    factory_iso9283: Annotated[
        Path | None, typer.Option(help="ISO 9283 criteria of the factory state (rxcomm/Iso9283).")
    ] = None,
    commissioned_iso9283: Annotated[
        Path | None, typer.Option(help="ISO 9283 criteria of the commissioned state (rxcomm/Iso9283).")
    ] = None,
    plot: Annotated[
        bool, typer.Option(help="Write time-energy.png beside the output: the time–energy curve.")
    ] = False,
) -> dict[str, object]:
    """Write the acceptance verdict: each criterion for the factory and the commissioned state."""
    from rxcomm.acceptance.verdict import acceptance_rows, overall

    output = Path(output)
    f_files = [_summary_file(Path(p)) for p in factory_log or []]
    c_files = [_summary_file(Path(p)) for p in commissioned_log or []]
    e_files = [_summary_file(Path(p)) for p in commissioned_equal_time_log or []]
    k_files = [_summary_file(Path(p)) for p in commissioned_curve_log or []]
    png = output.with_name("time-energy.png") if plot else None
    logs = {"factory": f_files, "commissioned": c_files, "commissioned_equal_time": e_files}
    logs["commissioned_curve"] = k_files
    inputs = _checked_inputs(thresholds, logs, factory_iso9283, commissioned_iso9283, output, png)
    spec = read_yaml_model(thresholds, AcceptanceThresholds)
    f_runs, c_runs, e_runs = (
        [read_yaml_artefact(p, RunLog).summary for p in f] for f in (f_files, c_files, e_files)
    )
    curve = _curve(k_files, len(c_files))
    f_iso = read_yaml_artefact(factory_iso9283, Iso9283) if factory_iso9283 else None
    c_iso = read_yaml_artefact(commissioned_iso9283, Iso9283) if commissioned_iso9283 else None
    rows = acceptance_rows(spec.criteria, f_runs, c_runs, f_iso, c_iso, e_runs, curve)
    summary = overall(rows)
    settings = {f"{k}_logs": [p.name for p in v] for k, v in logs.items()}
    used = {k: Path(v) for k, v in inputs.items() if v is not None}
    artefact = Acceptance(**Acceptance.envelope(used, settings, summary), rows=rows)
    write_yaml_artefact(output, artefact)
    if png is not None:
        plot_time_energy(png, [c_runs, e_runs, *curve], f_runs)
    print_verdict(artefact.summary, rows)
    console.out.print(f"verdict → {output}")
    return summary


def plot_time_energy(path: Path, commissioned: list, factory: list) -> Path:
    """The commissioned tasks' (cycle time, electrical energy) as a curve, the factory's point on it."""
    from rxcomm.acceptance.verdict import time_energy_points

    plt = plotting.pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    pts = time_energy_points(commissioned)
    if pts:
        ax.plot(*zip(*pts, strict=True), "o-", label="commissioned (energy objective; fastest: time-optimal)")
    for t, e in time_energy_points([factory]):
        ax.plot([t], [e], "s", color="C3", markersize=9, label="factory (catalogue timing)")
        ax.axvline(t, color="C3", lw=0.8, ls=":")
        ax.axhline(e, color="C3", lw=0.8, ls=":")
    ax.set_xlabel("cycle time of the reference task [s]")
    ax.set_ylabel("electrical energy [J]")
    ax.set_title("reference task: time–energy (measured runs)")
    ax.grid(alpha=0.3)
    ax.legend()
    return plotting.save_figure(fig, path)


def _curve(files: list[Path], moves: int) -> list[list[RunLogSummary]]:
    """The curve's run summaries in groups of the task's `moves` (one group per cycle time)."""
    runs = [read_yaml_artefact(p, RunLog).summary for p in files]
    moves = max(moves, 1)
    if len(runs) % moves:
        raise InputError(f"{len(runs)} curve run logs: not groups of {moves}", field="commissioned-curve-log")
    return [runs[i : i + moves] for i in range(0, len(runs), moves)]


def _checked_inputs(thresholds, logs: dict[str, list[Path]], f_iso, c_iso, output, png) -> dict:
    """Every input by name (NAME_log_i per log list), checked: outputs apart from inputs, files
    present, the same task (moves) in both states."""
    f_files, c_files = logs["factory"], logs["commissioned"]
    inputs = {"thresholds": Path(thresholds)}
    for kind, files in logs.items():
        inputs |= {f"{kind}_log_{i + 1}": p for i, p in enumerate(files)}
    inputs |= {"factory_iso9283": f_iso, "commissioned_iso9283": c_iso}
    check_outputs({"output": output, "plot": png}, inputs)
    for name, p in inputs.items():
        if p is not None and not Path(p).exists():
            raise InputError("file not found", file=p, field=name.replace("_", "-"))
    if len(f_files) != len(c_files):
        raise InputError(
            f"{len(f_files)} factory and {len(c_files)} commissioned run logs: the reference task is the "
            "same moves in both states",
            field="commissioned-log",
        )
    check_same_task(f_files, c_files)
    return inputs
