"""The ISO 9283 test-plane paths of a robot as path files (`iso9283-paths`, `import-robot`).

`iso9283_path_files` finds the largest reachable test cube (planning.iso9283) at one TCP orientation
and renders its paths as the YAML text of path files; `iso9283_path_files_any_orientation` tries the
tool-down, tool-forward and tool-up orientations in turn, for an arm whose wrist cannot turn the tool
down. Text in, text out: the stages write the files.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import dump_yaml
from rxcomm.model.robot import Robot
from rxcomm.planning.iso9283 import calibration_safe_branch, iso9283_cube_any_branch, iso9283_paths
from rxcomm.schemas.cell import Box

# The TCP orientations tried, in order (URDF roll, pitch, yaw in degrees): tool down, tool forward
# (+x), tool up.
ISO_ORIENTATIONS_DEG: tuple[tuple[float, float, float], ...] = ((180, 0, 0), (0, 90, 0), (0, 0, 0))


@dataclass(frozen=True)
class Iso9283PathFiles:
    """A test cube's facts (for the console) and its path files (file name → YAML text)."""

    facts: dict[str, object]
    texts: dict[str, str]
    rpy_deg: tuple[float, float, float]


def iso9283_path_files(
    robot: Robot, rpy_deg: Sequence[float], workspace: Box | None = None, written_by: str = "iso9283-paths"
) -> Iso9283PathFiles:
    """The robot's ISO 9283 test cube at TCP orientation `rpy_deg` inside `workspace` (base frame), and
    its test-plane path files. InputError where no cube is reachable."""
    cube, branch = iso9283_cube_any_branch(robot, tuple(np.radians(rpy_deg)), workspace=workspace)
    branch = calibration_safe_branch(robot, cube, branch)
    texts = {}
    for name, spec in iso9283_paths(cube, branch).items():
        header = f"# ISO 9283 test path for {robot.name}, written by `rxcomm {written_by}`.\n"
        data = spec.model_dump(mode="json", exclude_none=True)
        # a label left out is written null: an absent one would read as the default
        data["branch"] = spec.branch.model_dump(mode="json")
        if data["geometry"].get("points_m") is None:
            data["geometry"].pop("full", None)  # only meaningful for the three-point form
        if not data["limits"]:
            data.pop("limits")
        texts[f"{name}.yaml"] = header + dump_yaml(data)
    facts = {
        "cube_centre_m": cube.centre_m.tolist(),
        "cube_side_m": cube.side_m,
        "ik_branch": ", ".join(f"{k} {v or 'either'}" for k, v in branch.model_dump().items()),
        **{f"{k}_m": v.tolist() for k, v in cube.points_m.items()},
    }
    return Iso9283PathFiles(facts, texts, (float(rpy_deg[0]), float(rpy_deg[1]), float(rpy_deg[2])))


def iso9283_path_files_any_orientation(
    robot: Robot, workspace: Box | None = None, written_by: str = "iso9283-paths"
) -> Iso9283PathFiles:
    """`iso9283_path_files` at the first of `ISO_ORIENTATIONS_DEG` the arm reaches a test cube with."""
    for rpy in ISO_ORIENTATIONS_DEG:
        try:
            return iso9283_path_files(robot, rpy, workspace, written_by)
        except InputError as e:
            last = e
    tried = ", ".join(",".join(f"{a:g}" for a in rpy) for rpy in ISO_ORIENTATIONS_DEG)
    raise InputError(f"{last.reason}; also tried rpy {tried}°", field="paths")
