"""`rxcomm export ARTEFACT [-o OUT]`: an artefact in the form another tool takes, chosen by its kind.

The artefact says what it is (its envelope ``kind``, in the MCAP's metadata or the YAML); ``EXPORTERS``
maps each kind to the library call that writes its export. A trajectory (``plan-cp``, ``plan-ptp``,
``excite --trajectory-out``) becomes the controller CSV (t, q, q̇, q̈, τ_ff per joint); a run log (also
a stopped run's ``.mcap.part``) its ``/run/joints`` as CSV; a ``dynamics.yaml`` its base parameters ± σ
(``identify --params-out``'s table); a ``calibrate --mdh-out`` kinematics YAML its MDH + zero-offset
table. Other kinds plug in here with one entry.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from pathlib import Path
from typing import Annotated

import typer

from rxcomm import console
from rxcomm.errors import InputError

# kind -> (what the export is, default suffix, "module:function" of the library call (source, out) -> out).
# Named, not imported: `rxcomm --help` loads this module and must stay light (the library is loaded
# for the one kind exported).
EXPORTERS: dict[str, tuple[str, str, str]] = {
    "rxcomm/Trajectory": ("controller trajectory CSV", ".csv", "rxcomm.io.csv_export:export_trajectory_csv"),
    "rxcomm/RunLog": ("run log CSV", ".csv", "rxcomm.io.csv_export:export_run_log_csv"),
    "rxcomm/Dynamics": (
        "identified parameters ± σ CSV",
        ".csv",
        "rxcomm.identification.export:export_dynamics_csv",
    ),
    "rxcomm/Kinematics": (
        "calibrated MDH + zero-offset CSV",
        ".csv",
        "rxcomm.calibration.exports:export_kinematics_csv",
    ),
}


def exporter(kind: str) -> Callable[[Path, Path], Path]:
    """The library call that exports ``kind`` (KeyError if none)."""
    module, name = EXPORTERS[kind][2].split(":")
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


def default_output(source: Path, suffix: str) -> Path:
    name = source.name.removesuffix(".part").removesuffix(".mcap").removesuffix(".yaml")
    return source.with_name(name + suffix)


def execute(artefact: Path, output: Path | None = None) -> Path:
    kind, source = artefact_kind(artefact)
    if kind not in EXPORTERS:
        raise InputError(
            f"kind {kind!r} has no export (exportable: {', '.join(sorted(EXPORTERS))})",
            file=artefact,
            field="kind",
        )
    from rxcomm.io.files import check_outputs

    what, suffix, _ = EXPORTERS[kind]
    target = Path(output) if output is not None else default_output(source, suffix)
    # NAME.mcap stands for its summary NAME.yaml too: neither may be the export
    check_outputs({"output": target}, {"artefact": artefact, "source": source})
    out = exporter(kind)(source, target)
    console.out.print(f"{what} → {out}")
    return out


def command(
    artefact: Annotated[
        Path, typer.Argument(help="An rxcomm artefact: trajectory or run log MCAP (or its YAML).")
    ],
    output: Annotated[
        Path | None,
        typer.Option("-o", "--output", help="The export (default: NAME.csv beside the artefact)."),
    ] = None,
) -> None:
    """Export an artefact for another tool, by its kind: a trajectory as the controller CSV (t, q, q̇, q̈,
    τ_ff per joint), a run log as CSV, identified dynamics as the parameter table ± σ. Exit 2 if the
    file is no artefact or its kind has no export.

    Example: rxcomm export build/cp.mcap -o cp.csv
    """
    console.stage_command(execute)(artefact, output)
