"""`rxcomm export`'s calls that need the robot: a calibration as a controller file (with its parity
figure, `rxcomm.calibration.controller_files`) and a run log's ROS 2 bag with the tracker frame of a
calibration in /tf_static. Not a command of its own: `rxcomm.stages.export` names these."""

from __future__ import annotations

from pathlib import Path
from typing import Any


def _calibrated(source: Path, robot_dir: Path) -> tuple[Any, Any]:
    from rxcomm.calibration.loading import read_calibration
    from rxcomm.model.geometric_errors import ErrorModel
    from rxcomm.model.robot import load_robot

    robot = load_robot(robot_dir)
    art = read_calibration(source, robot)
    errors = ErrorModel.from_mapping(robot, {p.name: p.value for p in art.parameters}, file=str(source))
    return robot, errors


def _export(fmt: str, source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    from rxcomm.calibration.controller_files import HOLD_M, write_controller_file

    robot, errors = _calibrated(Path(source), Path(ctx["robot_dir"]))
    parity = write_controller_file(fmt, robot, errors, out, source=Path(source).name)
    summary: dict[str, Any] = {"parity": parity.as_dict()}
    if not parity.holds:
        summary["note"] = (
            f"{fmt} cannot hold this calibration to {HOLD_M * 1e6:g} µm "
            f"(it leaves {parity.max_position_m * 1e3:.3g} mm): export mdh-hayati or urdf"
        )
    return summary


def export_urdf(source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    return _export("urdf", source, out, ctx)


def export_joint_origins(source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    return _export("joint-origins", source, out, ctx)


def export_mdh(source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    return _export("mdh", source, out, ctx)


def export_mdh_hayati(source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    return _export("mdh-hayati", source, out, ctx)


def export_run_log_bag(source: Path, out: Path, ctx: dict[str, Any]) -> dict[str, Any]:
    """The run log's bag; with ``--calibration`` (and ``--robot`` for the root link's name, else
    ``base_link``) the tracker frame in /tf_static: the inverse of the calibration's tracker → base."""
    from rxcomm.io.trajectory_exports import export_run_log_bag as write

    tracker = None
    if ctx.get("calibration") is not None:
        from rxcomm.calibration.loading import load_calibration
        from rxcomm.model.kinematics import quaternion_wxyz

        _, t2b = load_calibration(ctx["calibration"])
        root = "base_link"
        if ctx.get("robot_dir") is not None:
            from rxcomm.model.robot import load_robot

            root = load_robot(ctx["robot_dir"]).model.frames[1].name
        inv = t2b.inverse()
        tracker = (
            root,
            [float(v) for v in inv.translation],
            [float(v) for v in quaternion_wxyz(inv.rotation)],
        )
    return write(source, out, tracker)
