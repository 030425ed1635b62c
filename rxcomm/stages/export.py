"""`rxcomm export ARTEFACT… [--format F] [-o OUT]`: artefacts in the forms other tools load, each with
its parity figure.

The artefact says what it is (its envelope ``kind``, in the MCAP's metadata or the YAML); ``EXPORTERS``
maps each kind to its formats (the first is the default) and each format to the library call that
writes it. Trajectories (``plan-cp``, ``plan-ptp``, ``excite``): ``csv``, ``ros2-trajectory``,
``ros2-bag``; run logs (also a stopped run's ``.mcap.part``): ``csv``, ``ros2-bag``; calibrations
(``--robot`` needed): ``urdf``, ``joint-origins``, ``mdh``, ``mdh-hayati``; ``dynamics.yaml``: its
parameter table ± σ; a ``calibrate --mdh-out`` kinematics YAML: its MDH CSV. docs/logs.md describes
every format. Each export's figure — a kinematic model's FK read back by an independent reader against
rxcomm's calibrated kinematics, a trajectory re-read against its samples — goes to the console and,
with ``--format all`` or several artefacts (``-o`` is then a directory), to ``parity.yaml`` there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer

from rxcomm import console
from rxcomm.errors import InputError
from rxcomm.io.files import check_outputs
from rxcomm.options import ROBOT

# kind -> format -> (what the export is, default suffix, "module:function" (source, out[, ctx]) -> summary).
# Named, not imported: `rxcomm --help` loads this module and must stay light.
_TRAJ = "rxcomm.io.trajectory_exports"
_CAL = "rxcomm.stages.export_calibration"
EXPORTERS: dict[str, dict[str, tuple[str, str, str]]] = {
    "rxcomm/Trajectory": {
        "csv": ("controller trajectory CSV", ".csv", f"{_TRAJ}:export_trajectory_csv"),
        "ros2-trajectory": (
            "ROS 2 JointTrajectory YAML",
            ".ros2-trajectory.yaml",
            f"{_TRAJ}:export_trajectory_ros2",
        ),
        "ros2-bag": ("ROS 2 bag (MCAP, CDR)", ".ros2.mcap", f"{_TRAJ}:export_trajectory_bag"),
    },
    "rxcomm/RunLog": {
        "csv": ("run log CSV", ".csv", f"{_TRAJ}:export_run_log_csv"),
        "ros2-bag": ("ROS 2 bag (MCAP, CDR)", ".ros2.mcap", f"{_CAL}:export_run_log_bag"),
    },
    "rxcomm/Calibration": {
        fmt: (what, suffix, f"{_CAL}:export_{fmt.replace('-', '_')}")
        for fmt, (what, suffix) in {
            "urdf": ("calibrated URDF (TCP link)", ".urdf"),
            "joint-origins": ("per-joint origin table", ".joint-origins.yaml"),
            "mdh": ("modified DH table (plain)", ".mdh.yaml"),
            "mdh-hayati": ("modified DH table with Hayati's beta", ".mdh-hayati.yaml"),
        }.items()
    },
    "rxcomm/Dynamics": {
        "csv": ("identified parameters ± σ CSV", ".csv", "rxcomm.identification.export:export_dynamics_csv")
    },
    "rxcomm/Kinematics": {
        "csv": (
            "calibrated MDH + zero-offset CSV",
            ".csv",
            "rxcomm.calibration.exports:export_kinematics_csv",
        )
    },
}
NEEDS_ROBOT = {"rxcomm/Calibration"}
PARITY_TABLE = "parity.yaml"


def exporter(kind: str, fmt: str | None = None) -> Callable[..., Any]:
    """The library call that exports ``kind`` as ``fmt`` (default: the kind's first; KeyError if none)."""
    formats = EXPORTERS[kind]
    module, name = formats[fmt or next(iter(formats))][2].split(":")
    return getattr(importlib.import_module(module), name)


def artefact_kind(path: Path) -> tuple[str, Path]:
    """(kind, the file holding the data): an MCAP's envelope, or a YAML's ``kind`` (a summary YAML
    beside an MCAP stands for that MCAP)."""
    from rxcomm.io.mcap_io import read_mcap_envelope
    from rxcomm.io.yaml_io import load_yaml

    if path.suffix == ".yaml":
        doc = load_yaml(path)
        kind = doc.get("kind") if isinstance(doc, dict) else None
        if not isinstance(kind, str):
            raise InputError("no artefact kind", file=path, field="kind")
        mcap = doc.get("mcap_file")
        return kind, (path.with_name(mcap) if isinstance(mcap, str) else path)
    kind = read_mcap_envelope(path).get("kind")
    if not isinstance(kind, str):
        raise InputError("no artefact kind in the envelope", file=path, field="envelope.kind")
    return kind, path


def default_output(source: Path, suffix: str, directory: Path | None = None) -> Path:
    name = source.name.removesuffix(".part").removesuffix(".mcap").removesuffix(".yaml")
    return (directory or source.parent) / (name + suffix)


def _formats(kind: str, fmt: str | None, artefact: Path) -> list[str]:
    if kind not in EXPORTERS:
        raise InputError(
            f"kind {kind!r} has no export (exportable: {', '.join(sorted(EXPORTERS))})",
            file=artefact,
            field="kind",
        )
    formats = EXPORTERS[kind]
    if fmt in (None, "all"):
        return list(formats) if fmt == "all" else [next(iter(formats))]
    if fmt not in formats:
        raise InputError(f"a {kind} exports as {', '.join(formats)} (or all), not {fmt!r}", field="format")
    return [fmt]


def _jobs(artefacts: list[Path], fmt: str | None, output: Path | None) -> tuple[list[tuple], Path | None]:
    """(kind, source, artefact, format, out) per export, and the directory of the parity table."""
    many = fmt == "all" or len(artefacts) > 1
    if many and output is not None and output.suffix:
        raise InputError("with --format all or several artefacts, -o is a directory", field="output")
    directory = output if many else None
    jobs = []
    for artefact in artefacts:
        kind, source = artefact_kind(artefact)
        for f in _formats(kind, fmt, artefact):
            suffix = EXPORTERS[kind][f][1]
            out = default_output(source, suffix, directory) if many or output is None else output
            jobs.append((kind, source, artefact, f, out))
    return jobs, (directory or (output.parent if output else None)) if many else None


def _print(what: str, out: Path, summary: dict[str, Any]) -> None:
    line = f"{what} → {out}"
    parity = summary.get("parity")
    if parity:
        line += (
            f"\n  parity ({parity['reader']}, {parity['n_poses']} poses): max "
            f"{parity['max_position_m'] * 1e6:.3g} µm, {parity['max_orientation_rad'] * 1e6:.3g} µrad"
        )
        if not parity["holds_1um"]:
            line += f"\n  {summary.get('note', 'does not hold the calibration to 1 µm')}"
    reread = summary.get("re-read")
    if reread:
        line += (
            f"\n  re-read by {reread['reader']}: max difference {reread['max_value_difference']:.3g}, "
            f"times {reread['max_time_difference_s']:.3g} s ({reread['precision']})"
        )
    console.out.print(line)


def execute(
    artefacts: list[Path] | Path,
    output: Path | None = None,
    fmt: str | None = None,
    robot_dir: Path | None = None,
    calibration: Path | None = None,
) -> list[dict[str, Any]]:
    """Write the exports; return one summary per file (format, file, source, figures). Raises RxcommError."""
    from rxcomm.io.files import atomic_write_text
    from rxcomm.io.yaml_io import dump_yaml

    artefacts = [Path(a) for a in (artefacts if isinstance(artefacts, list) else [artefacts])]
    jobs, table_dir = _jobs(artefacts, fmt, Path(output) if output else None)
    if any(kind in NEEDS_ROBOT for kind, *_ in jobs) and robot_dir is None:
        raise InputError("a calibration exports on its robot: pass --robot", field="robot")
    files = {f"output {i}": out for i, (*_, out) in enumerate(jobs)}
    table = table_dir / PARITY_TABLE if table_dir else None
    sources = {f"source {i}": source for i, (_, source, *_) in enumerate(jobs)}  # a YAML's MCAP too
    check_outputs(
        {**files, "parity": table}, {**{f"artefact {i}": a for i, a in enumerate(artefacts)}, **sources}
    )
    ctx = {"robot_dir": robot_dir, "calibration": calibration}
    rows = []
    for kind, source, _, f, out in jobs:
        out.parent.mkdir(parents=True, exist_ok=True)
        call = exporter(kind, f)
        needs = kind in NEEDS_ROBOT or (kind, f) == ("rxcomm/RunLog", "ros2-bag")
        result = call(source, out, ctx) if needs else call(source, out)
        summary = result if isinstance(result, dict) else {}
        _print(EXPORTERS[kind][f][0], out, summary)
        rows.append({"format": f, "file": out.name, "source": source.name, **summary})
    if table is not None:
        atomic_write_text(table, dump_yaml({"kind": "rxcomm/ExportParity", "exports": rows}))
        console.out.print(f"parity table → {table}")
    return rows


def command(
    artefacts: Annotated[
        list[Path],
        typer.Argument(
            help="rxcomm artefacts: trajectory or run log MCAP (or its YAML), calibration.yaml, …"
        ),
    ],
    output: Annotated[
        Path | None,
        typer.Option(
            "-o", "--output", help="The export (default: beside the artefact); a directory with all/several."
        ),
    ] = None,
    fmt: Annotated[
        str | None,
        typer.Option(
            "--format",
            help="trajectory: csv, ros2-trajectory, ros2-bag; run log: csv, ros2-bag; calibration: urdf, "
            "joint-origins, mdh, mdh-hayati; all: every format of the kind (default: the first).",
        ),
    ] = None,
    robot_dir: Annotated[
        Path | None, ROBOT  # a calibration's exports
    ] = None,
    calibration: Annotated[
        Path | None,
        typer.Option(help="calibration.yaml: the tracker frame in a run log's ROS 2 bag (/tf_static)."),
    ] = None,
) -> None:
    """Export artefacts for other tools, by kind and --format, each with its parity figure (a kinematic
    model's FK read back by an independent reader vs rxcomm's calibrated FK; a trajectory re-read vs
    its samples). Exit 2 if a file is no artefact, its kind has no such format or --robot is missing.

    Example: rxcomm export build/calibration.yaml build/cp.mcap --robot samples/rx130l --format all -o exports
    """
    console.stage_command(execute)(artefacts, output, fmt, robot_dir, calibration)
