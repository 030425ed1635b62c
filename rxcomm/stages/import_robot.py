"""`rxcomm import-robot MODEL.xml|MODEL.urdf -o DIR`: a robot directory from a MuJoCo model.

Writes DIR/NAME.urdf (kinematics and inertias from MuJoCo's compiled model), DIR/drives.yaml (friction
priors, rotor inertias, peak torques and limits from the model; everything else a stated default
marked *assumed*) and keeps the model file beside them (DIR/NAME.mujoco.xml or .urdf) as its source.
So that `make commission ROBOT=DIR` runs at once, it also writes what a model cannot hold, each file
headed ASSUMED: DIR/cell.yaml (`rxcomm.model.cell_layout`: floor, tracker, workspace scaled by reach),
DIR/paths/ (the ISO 9283 test paths in that cell, `iso9283-paths`) and DIR/acceptance.yaml
(`rxcomm.acceptance.defaults`: ratios to the factory state); any of these DIR already has is kept,
never overwritten. The directory is loaded back as a robot before anything is moved into DIR. Exit 2:
not a serial 6R arm (the joint or body that breaks it named), a model MuJoCo cannot read, an output
that cannot be written.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from rxcomm import console
from rxcomm.errors import InputError

if TYPE_CHECKING:
    from rxcomm.model.robot import Robot


def command(
    model: Annotated[Path, typer.Argument(help="A MuJoCo model: MJCF (MODEL.xml) or URDF.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="The robot directory to write.")],
) -> None:
    """Write a robot directory (URDF + drives.yaml, the model kept beside) from a MuJoCo model."""
    console.stage_command(run)(model, output)


def run(model: Path, output: Path) -> dict[str, object]:
    """The stage as a function: returns what it wrote and what it assumed."""
    from rxcomm.io.files import atomic_write_bytes, atomic_write_text
    from rxcomm.io.yaml_io import dump_yaml
    from rxcomm.model.mjcf_import import import_model
    from rxcomm.model.robot import load_robot

    model, output = Path(model), Path(output)
    if output.exists() and not output.is_dir():
        raise InputError("is a file; name a directory to write the robot into", file=output, field="output")
    imported = import_model(model)
    source_name = f"{imported.name}.mujoco{model.suffix}"
    header = (
        f"# Imported by `rxcomm import-robot` from {model.name} (kept beside as {source_name}).\n"
        "# ASSUMED (a MuJoCo model does not hold them; replace with the maker's data):\n"
        + "".join(f"#   - {a}\n" for a in imported.assumed)
    )
    files = {
        f"{imported.name}.urdf": imported.urdf,
        "drives.yaml": header + dump_yaml(imported.drives),
    }
    output.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=output, prefix=".import-") as tmp:
        for name, text in files.items():
            (Path(tmp) / name).write_text(text)
        robot = load_robot(tmp)  # what we write must load as a robot, or nothing is written
        cell = _cell_files(robot, Path(tmp), output)
        for name, text in files.items():
            atomic_write_text(output / name, text)
        atomic_write_bytes(output / source_name, model.read_bytes())
        for name in cell.written:
            (Path(tmp) / name).replace(output / name)
    out = console.out
    out.print(f"robot {imported.name}: {robot.n} joints {list(robot.joint_names)} → {output}")
    for note in imported.notes:
        out.print(f"  note: {note}")
    out.print("  [bold]assumed[/] (written to drives.yaml with this list at its top):")
    for a in imported.assumed:
        out.print(f"    - {a}")
    for name in cell.kept:
        out.print(f"  kept {escape(str(output / name))} (already there)")
    if cell.notes:
        out.print(
            "  [bold]assumed cell[/] (cell.yaml; the ISO 9283 paths in it; acceptance.yaml: mostly ratios "
            "to the factory):"
        )
        for note in cell.notes:
            out.print(f"    - {note}")
    return {"robot": str(output), "joints": list(robot.joint_names), "assumed": imported.assumed}


@dataclass(frozen=True)
class _CellFiles:
    written: list[str]
    kept: list[str]
    notes: list[str]


def _cell_files(robot: Robot, tmp: Path, output: Path) -> _CellFiles:
    """cell.yaml, acceptance.yaml and paths/ in `tmp` where `output` lacks them (the paths are found in
    the cell `output` will hold)."""
    from rxcomm.acceptance.defaults import default_thresholds
    from rxcomm.io.files import atomic_write_text
    from rxcomm.io.yaml_io import dump_yaml
    from rxcomm.model.cell_layout import default_cell, layout_notes

    written, kept = [], []
    notes: list[str] = []
    defaults = {
        "cell.yaml": (CELL_HEADER, lambda: default_cell(robot)),
        "acceptance.yaml": (ACCEPTANCE_HEADER, default_thresholds),
    }
    for name, (head, make) in defaults.items():
        if (output / name).exists():
            kept.append(name)
            continue
        atomic_write_text(tmp / name, head + dump_yaml(make().model_dump(mode="json", exclude_none=True)))
        written.append(name)
    if "cell.yaml" in written:
        notes += layout_notes(robot)
    if (output / "paths").exists():
        kept.append("paths")
    else:
        cell = output / "cell.yaml" if "cell.yaml" in kept else tmp / "cell.yaml"
        texts, rpy = _iso9283_texts(robot, cell)
        notes.append(f"ISO 9283 paths with the TCP at rpy {rpy}° (base frame)")
        (tmp / "paths").mkdir()
        for name, text in texts.items():
            atomic_write_text(tmp / "paths" / name, text)
        written.append("paths")
    return _CellFiles(written, kept, notes)


# The TCP orientations tried for the ISO 9283 paths, in order: tool down, tool forward (+x), tool up.
ISO_ORIENTATIONS_DEG = ("180,0,0", "0,90,0", "0,0,0")


def _iso9283_texts(robot: Robot, cell: Path) -> tuple[dict[str, str], str]:
    """The ISO 9283 path files at the first of `ISO_ORIENTATIONS_DEG` the arm reaches a test cube with
    (a wrist that cannot turn the tool down has its cube with the tool forward)."""
    from rxcomm.stages.iso9283_paths import iso9283_path_files

    for rpy in ISO_ORIENTATIONS_DEG:
        try:
            return iso9283_path_files(robot, cell, rpy)[1], rpy
        except InputError as e:
            last = e
    raise InputError(f"{last.reason}; also tried rpy {', '.join(ISO_ORIENTATIONS_DEG)}°", field="paths")


CELL_HEADER = (
    "# ASSUMED by `rxcomm import-robot` (rxcomm/model/cell_layout.py): a cell laid out by the robot's\n"
    "# reach. Replace with the real cell: floor, tracker placement and noise, workspace, allowed region.\n"
)
ACCEPTANCE_HEADER = (
    "# ASSUMED by `rxcomm import-robot` (rxcomm/acceptance/defaults.py): ratios to the factory state\n"
    "# measured the same way, repeatability within the tracker's noise. Replace with the customer's.\n"
)
