"""`rxcomm iso9283-paths`: the robot's ISO 9283 test-plane paths, as path files for plan-cp and friends.

Finds the largest cube (ISO 9283 §6.2) the robot reaches at the given TCP orientation (inside the
`--cell` workspace when given) and writes its test paths (line, circles, rectangle: the rectangle also
defines the pose test's P1–P5) to the directory `-o`. Was `plan-cp --iso9283 DIR` (a hidden alias now,
with a deprecation note).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.markup import escape

from rxcomm import console
from rxcomm.io.files import atomic_write_text
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.options import CellFile, RobotDir, parse_numbers
from rxcomm.schemas.cell import Cell
from rxcomm.stages.declarations import DECLARATIONS

if TYPE_CHECKING:
    from rxcomm.model.robot import Robot


def write_iso9283(robot: Robot, out_dir: Path, cell: Path | None, rpy_deg: str) -> dict[str, object]:
    """Find the robot's ISO 9283 test cube and write its test-plane paths to `out_dir`."""
    from rxcomm.planning.iso9283_files import iso9283_path_files

    rpy = parse_numbers(rpy_deg, 3, "tcp-rpy-deg", "degrees")
    box = read_yaml_model(cell, Cell).workspace.box_above_floor() if cell is not None else None
    with console.phase("iso9283-paths: searching the largest reachable ISO 9283 cube"):
        files = iso9283_path_files(robot, rpy, box)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in files.texts.items():
        atomic_write_text(out_dir / name, text)
        written.append(str(out_dir / name))
    console.summary_table(f"ISO 9283 test cube of {robot.name}", files.facts)
    for f in written:
        console.out.print(f"  wrote {escape(f)}")
    return files.facts | {"files": written}


@console.stage_command
def command(
    robot_dir: RobotDir,
    output: Annotated[Path, typer.Option("-o", "--output", help="Directory to write the path files into.")],
    cell: CellFile = None,
    tcp_rpy_deg: Annotated[
        str, typer.Option(help="TCP orientation on the paths: URDF roll,pitch,yaw in degrees.")
    ] = "180,0,0",
) -> dict[str, object]:
    """Write the robot's ISO 9283 test-plane paths (line, circles, rectangle) as path files to a directory."""
    from rxcomm.model.robot import load_robot

    DECLARATIONS["iso9283-paths"].check(output=output, robot=robot_dir, cell=cell)
    return write_iso9283(load_robot(robot_dir), Path(output), cell, tcp_rpy_deg)
