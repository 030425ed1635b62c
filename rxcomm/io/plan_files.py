"""A plan for `run` in any of the forms rxcomm writes: its trajectory MCAP, the controller CSV
(`rxcomm.io.csv_export`) or a ROS 2 ``JointTrajectory`` YAML (`rxcomm.io.ros2_trajectory`), so a
trajectory edited or produced elsewhere can be executed. Only the samples are read (t, q, q̇, q̈);
`run` resamples them at the drive cycle, computes its own feed-forward torque and checks every limit
as for its own plans. ``PlanFile.label(i)`` names sample i as the file does (CSV ``row`` from 1 at the
first data row, YAML ``points[i]``, MCAP ``sample i``), for a refusal to point at it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from rxcomm.errors import InputError
from rxcomm.io.trajectory import Trajectory

FORMATS = {".mcap": "trajectory MCAP", ".csv": "trajectory CSV", ".yaml": "ROS 2 JointTrajectory YAML"}


@dataclass(frozen=True)
class PlanFile:
    trajectory: Trajectory
    joint_names: list[str] | None  # None: the file names no joints (an old CSV: joint1 …)
    form: str

    def label(self, i: int) -> str:
        if self.form == ".csv":
            return f"row {i + 1}"
        if self.form == ".yaml":
            return f"points[{i}]"
        return f"sample {i}"


def is_trajectory_yaml(path: Path) -> bool:
    """A YAML plan that is a JointTrajectory (``joint_names`` and ``points``), not a pose list."""
    from rxcomm.io.ros2_trajectory import is_ros2_trajectory
    from rxcomm.io.yaml_io import load_yaml

    return is_ros2_trajectory(load_yaml(path))


def plan_kind(plan: Path) -> str:
    """`run`'s PLAN: 'trajectory' for NAME.mcap, a trajectory CSV or a JointTrajectory YAML; 'poses'
    for a YAML pose list."""
    suffix = plan.suffix.lower()
    if suffix in (".mcap", ".csv"):
        return "trajectory"
    if suffix in (".yaml", ".yml"):
        return "trajectory" if is_trajectory_yaml(plan) else "poses"
    raise InputError(
        "PLAN must be a trajectory (.mcap, .csv, JointTrajectory .yaml) or a pose list", file=plan
    )


def load_plan_file(path: str | Path, joint_names: Sequence[str] | None = None) -> PlanFile:
    """The plan of ``path`` by its suffix (.mcap, .csv, .yaml/.yml); InputError names what is wrong,
    also joints other than ``joint_names`` (the robot's) where the file names its joints."""
    plan = _load(Path(path))
    if joint_names is not None and plan.joint_names is not None and plan.joint_names != list(joint_names):
        raise InputError(
            f"plan is for joints {plan.joint_names}, the robot has {list(joint_names)}",
            file=path,
            field="joint_names",
        )
    return plan


def _load(path: Path) -> PlanFile:
    suffix = ".yaml" if path.suffix.lower() == ".yml" else path.suffix.lower()
    if suffix == ".mcap":
        from rxcomm.io.trajectory import load_trajectory_named

        traj, _, names = load_trajectory_named(path)
        return PlanFile(traj, names, suffix)
    if suffix == ".csv":
        from rxcomm.io.csv_export import read_trajectory_csv_named

        traj, names = read_trajectory_csv_named(path)
        return PlanFile(traj, names, suffix)
    if suffix == ".yaml":
        from rxcomm.io.ros2_trajectory import read_ros2_trajectory

        traj, names = read_ros2_trajectory(path)
        return PlanFile(traj, names, suffix)
    raise InputError(f"a plan is one of {', '.join(FORMATS.values())} ({', '.join(FORMATS)})", file=path)
