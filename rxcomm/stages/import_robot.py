"""`rxcomm import-robot MODEL.xml|MODEL.urdf -o DIR`: a robot directory from a MuJoCo model.

Writes DIR/NAME.urdf (kinematics and inertias from MuJoCo's compiled model), DIR/drives.yaml (friction
priors, rotor inertias, peak torques and limits from the model; everything else a stated default
marked *assumed*) and keeps the model file beside them (DIR/NAME.mujoco.xml or .urdf) as its source.
So that `make commission ROBOT=DIR` runs at once, it also writes what a model cannot hold, each file
headed ASSUMED: DIR/cell.yaml (`rxcomm.model.cell_layout`: floor, tracker, workspace scaled by reach),
DIR/paths/ (the ISO 9283 test paths in that cell, as `iso9283-paths` writes them) and
DIR/acceptance.yaml (`rxcomm.acceptance.defaults`: ratios to the factory state), all made by
`rxcomm.acceptance.assumed_cell`; any of these DIR already has is kept, never overwritten. The robot
is loaded back and every file made before anything is written into DIR. Exit 2: not a serial 6R arm
(the joint or body that breaks it named), a model MuJoCo cannot read, no reachable ISO 9283 cube, an
output that cannot be written.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from rxcomm import console
from rxcomm.errors import InputError


def command(
    model: Annotated[Path, typer.Argument(help="A MuJoCo model: MJCF (MODEL.xml) or URDF.")],
    output: Annotated[Path, typer.Option("-o", "--output", help="The robot directory to write.")],
) -> None:
    """Write a robot directory (URDF + drives.yaml, the model kept beside) from a MuJoCo model."""
    console.stage_command(run)(model, output)


def run(model: Path, output: Path) -> dict[str, object]:
    """The stage as a function: returns what it wrote and what it assumed."""
    from rxcomm.acceptance.assumed_cell import ACCEPTANCE_FILE, CELL_FILE, PATHS_DIR, assumed_cell_files
    from rxcomm.io.files import atomic_write_bytes, atomic_write_text
    from rxcomm.io.yaml_io import dump_yaml, read_yaml_model
    from rxcomm.model.mjcf_import import import_model
    from rxcomm.model.robot import load_robot
    from rxcomm.schemas.cell import Cell

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
    present = [name for name in (CELL_FILE, ACCEPTANCE_FILE, PATHS_DIR) if (output / name).exists()]
    own_cell = read_yaml_model(output / CELL_FILE, Cell) if CELL_FILE in present else None
    created = not output.exists()
    output.mkdir(parents=True, exist_ok=True)
    try:
        with tempfile.TemporaryDirectory(dir=output, prefix=".import-") as tmp:
            for name, text in files.items():
                (Path(tmp) / name).write_text(text)
            robot = load_robot(tmp)  # what we write must load as a robot, or nothing is written
            cell = assumed_cell_files(robot, present, own_cell)
            for name, text in files.items():
                atomic_write_text(output / name, text)
            atomic_write_bytes(output / source_name, model.read_bytes())
            for name, text in cell.texts.items():
                (output / name).parent.mkdir(exist_ok=True)
                atomic_write_text(output / name, text)
    except Exception:
        if created and not any(output.iterdir()):  # nor an empty robot directory left behind
            output.rmdir()
        raise

    out = console.out
    out.print(f"robot {imported.name}: {robot.n} joints {list(robot.joint_names)} → {output}")
    for note in imported.notes:
        out.print(f"  note: {note}")
    out.print("  [bold]assumed[/] (written to drives.yaml with this list at its top):")
    for a in imported.assumed:
        out.print(f"    - {a}")
    for name in present:
        out.print(f"  kept {escape(str(output / name))} (already there)")
    if cell.notes:
        out.print(
            "  [bold]assumed cell[/] (cell.yaml; the ISO 9283 paths in it; acceptance.yaml: mostly ratios "
            "to the factory):"
        )
        for note in cell.notes:
            out.print(f"    - {note}")
    return {"robot": str(output), "joints": list(robot.joint_names), "assumed": imported.assumed}
