"""What a commissioning needs beyond the robot, assumed for a robot that comes without it
(`import-robot`): the cell (`model.cell_layout`), its ISO 9283 test paths (`planning.iso9283_files`)
and the acceptance thresholds (`acceptance.defaults`).

Each file's text is headed ASSUMED and says where its choices come from; `notes` says them again with
this robot's numbers, for the console. A file the robot directory already has is not made: the
paths are found in the cell the directory will hold (its own when it has one).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

from rxcomm.acceptance.defaults import default_thresholds
from rxcomm.io.yaml_io import dump_yaml
from rxcomm.model.cell_layout import default_cell, layout_notes
from rxcomm.model.robot import Robot
from rxcomm.planning.iso9283_files import iso9283_path_files_any_orientation
from rxcomm.schemas.cell import Cell

CELL_HEADER = (
    "# ASSUMED by `rxcomm import-robot` (rxcomm/model/cell_layout.py): a cell laid out by the robot's\n"
    "# reach. Replace with the real cell: floor, tracker placement and noise, workspace, allowed region.\n"
)
ACCEPTANCE_HEADER = (
    "# ASSUMED by `rxcomm import-robot` (rxcomm/acceptance/defaults.py): ratios to the factory state\n"
    "# measured the same way, repeatability within the tracker's noise. Replace with the customer's.\n"
)
# the robot directory's entries made here: two files and the directory of path files
CELL_FILE, ACCEPTANCE_FILE, PATHS_DIR = "cell.yaml", "acceptance.yaml", "paths"


@dataclass(frozen=True)
class AssumedCellFiles:
    """Relative path in the robot directory → text, for the entries it lacked; what was assumed."""

    texts: dict[str, str]
    notes: list[str]


def assumed_cell_files(
    robot: Robot, present: Collection[str], own_cell: Cell | None = None
) -> AssumedCellFiles:
    """The cell, acceptance and path files for `robot`'s directory, leaving out the entries `present`
    (names among CELL_FILE, ACCEPTANCE_FILE, PATHS_DIR); `own_cell` is the directory's cell when it
    has one. InputError where the arm reaches no ISO 9283 test cube in its cell."""
    texts: dict[str, str] = {}
    notes: list[str] = []
    cell = own_cell
    if CELL_FILE not in present:
        cell = default_cell(robot)
        texts[CELL_FILE] = CELL_HEADER + dump_yaml(cell.model_dump(mode="json", exclude_none=True))
        notes += layout_notes(robot)
    if ACCEPTANCE_FILE not in present:
        thresholds = default_thresholds().model_dump(mode="json", exclude_none=True)
        texts[ACCEPTANCE_FILE] = ACCEPTANCE_HEADER + dump_yaml(thresholds)
    if PATHS_DIR not in present:
        box = cell.workspace.box_above_floor() if cell is not None else None
        paths = iso9283_path_files_any_orientation(robot, box, written_by="import-robot")
        notes.append(
            f"ISO 9283 paths with the TCP at rpy {','.join(f'{a:g}' for a in paths.rpy_deg)}° (base frame)"
        )
        texts |= {f"{PATHS_DIR}/{name}": text for name, text in paths.texts.items()}
    return AssumedCellFiles(texts, notes)
