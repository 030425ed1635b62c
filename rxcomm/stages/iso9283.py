"""`rxcomm iso9283`: the ISO 9283 performance criteria of one robot state, from run logs with tracker data.

Inputs: the robot, the ISO 9283 path specs (`rxcomm iso9283-paths`; the rectangle defines the test
cube), the base frame the tracker measures in (`--calibration`: its nominal `tracker_to_base`, or
`--cell`), and run logs with a ``/run/tracker`` channel: pose-cycle logs (P1 → P5 → P4 → P3 → P2 per
cycle, with dwells) and one log per cycle of each test path. Writes ``iso9283.yaml`` (kind
`rxcomm/Iso9283`: per criterion, target, value or null = not measured, unit, cycles, command speed)
and prints the table; `--plot` draws AP/RP per pose and AT/RT per path beside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model, write_yaml_artefact
from rxcomm.options import CELL, Iso9283Paths, RobotDir
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.cell import Cell
from rxcomm.schemas.iso9283 import BaseFrame, CubeDefinition, Iso9283, Iso9283Summary
from rxcomm.schemas.path import PathSpec
from rxcomm.stages.declarations import DECLARATIONS

if TYPE_CHECKING:
    from rxcomm.acceptance.campaign import EvaluationSettings


def base_frame(calibration: Path | None, cell: Path | None) -> BaseFrame:
    if (calibration is None) == (cell is None):
        raise InputError("give one of --calibration or --cell (the base frame in the tracker frame)")
    if calibration is not None:
        p = read_yaml_artefact(calibration, Calibration).tracker_to_base
        return BaseFrame(xyz_m=p.xyz_m, rpy_rad=p.rpy_rad, source="calibration")
    tracker = read_yaml_model(cell, Cell).tracker
    if tracker is None:
        raise InputError("the cell has no tracker", file=cell, field="tracker")
    p = tracker.tracker_to_base
    return BaseFrame(xyz_m=p.xyz_m, rpy_rad=p.rpy_rad, source="cell")


def read_specs(paths_dir: Path) -> dict[str, PathSpec]:
    from rxcomm.acceptance.campaign import PATH_TARGETS

    specs = {}
    for target in PATH_TARGETS:
        f = paths_dir / f"{target}.yaml"
        if f.is_file():
            specs[target] = read_yaml_model(f, PathSpec)
    return specs


# The option of each test path's logs (`path_logs` keys: acceptance.campaign.PATH_TARGETS).
LOG_OPTIONS = {
    "iso9283-line": "line-log",
    "iso9283-circle-large": "circle-log",
    "iso9283-circle-small": "small-circle-log",
    "iso9283-rectangle": "rectangle-log",
}


def execute(
    robot_dir: Path,
    output: Path,
    *,
    pose_logs: list[Path],
    path_logs: dict[str, list[Path]],
    paths_dir: Path | None = None,
    calibration: Path | None = None,
    cell: Path | None = None,
    settings: EvaluationSettings | None = None,
    plot: bool = False,
) -> Iso9283:
    """The stage as a function (tests call it): returns the artefact written. Raises RxcommError."""
    from rxcomm.acceptance.campaign import EvaluationSettings, evaluate
    from rxcomm.model.geometric_errors import placement_to_se3
    from rxcomm.model.robot import load_robot

    output = Path(output)
    paths_dir = Path(paths_dir) if paths_dir is not None else Path(robot_dir) / "paths"
    unknown = set(path_logs) - set(LOG_OPTIONS)
    if unknown:
        raise InputError(f"no ISO 9283 test path {sorted(unknown)}", field="path_logs")
    by_option = {option: path_logs.get(target, []) for target, option in LOG_OPTIONS.items()}
    files = {"pose-log": pose_logs, "paths": paths_dir, "calibration": calibration, "cell": cell, **by_option}
    DECLARATIONS["iso9283"].check(output=output, plot=plot, robot=robot_dir, **files)
    s = settings or EvaluationSettings()
    frame = base_frame(calibration, cell)
    robot = load_robot(robot_dir)
    specs = read_specs(paths_dir)
    t2b = placement_to_se3(frame.xyz_m, frame.rpy_rad)
    cube, criteria, cond = evaluate(robot, specs, t2b, pose_logs, path_logs, s)
    n_measured = sum(c.value is not None for c in criteria)
    # the pose test's conditions (ISO 9283 asks a report to state them); the values are in `criteria`
    summary = Iso9283Summary(n_criteria=len(criteria), n_measured=n_measured, **vars(cond))
    logs = {f"pose log {i + 1}": p for i, p in enumerate(pose_logs)}  # the envelope's input names
    logs |= {f"{t} log {i + 1}": p for t, ps in path_logs.items() for i, p in enumerate(ps)}
    inputs = {**logs, "urdf": robot.urdf_path, "drives": robot.drives_path}
    inputs |= {f"path {t}": paths_dir / f"{t}.yaml" for t in specs}
    if calibration is not None:
        inputs["calibration"] = calibration
    if cell is not None:
        inputs["cell"] = cell
    art = Iso9283(
        **Iso9283.envelope(inputs, {**s.model_dump(mode="json"), "paths": str(paths_dir)}, summary),
        robot=robot.name,
        cube=CubeDefinition(
            centre_m=tuple(cube.centre_m),
            side_m=cube.side_m,
            rpy_rad=cube.rpy_rad,
            plane_corners_m=[tuple(c) for c in cube.plane_corners_m],
            points_m={k: tuple(v) for k, v in cube.points_m.items()},
        ),
        base_frame=frame,
        criteria=criteria,
    )
    write_yaml_artefact(output, art)
    print_table(art)
    console.out.print(f"ISO 9283 criteria → {output}")
    if plot:
        figure = plot_criteria(art, output.with_suffix(".png"))
        console.out.print(f"figure: {figure}")
    return art


SCALE = {"m": (1e3, "mm"), "rad": (1e3, "mrad"), "1": (100.0, "%")}


def print_table(art: Iso9283) -> None:
    console.out.print(
        f"[bold]ISO 9283 — {art.robot}[/] (cube {art.cube.side_m:.2f} m, base frame: {art.base_frame.source})"
    )
    console.out.print(f"  {'criterion':<6} {'target':<22} {'value':>12} {'cycles':>6} {'speed m/s':>9}")
    for c in art.criteria:
        k, unit = SCALE[c.unit]
        value = "not measured" if c.value is None else f"{c.value * k:.4g} {unit}"
        cycles = "" if c.cycles is None else str(c.cycles)
        speed = "" if c.command_speed_m_per_s is None else f"{c.command_speed_m_per_s:.3g}"
        console.out.print(f"  {c.key:<6} {c.target:<22} {value:>12} {cycles:>6} {speed:>9}")


def plot_criteria(art: Iso9283, out: Path) -> Path:
    """AP_p and RP_l per test pose, AT_p and RT_p per test path (mm); measured ones only."""
    plt = plotting.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, keys, title in (
        (axes[0], ("AP_p", "RP_l"), "pose accuracy / repeatability"),
        (axes[1], ("AT_p", "RT_p"), "path accuracy / repeatability"),
    ):
        for j, key in enumerate(keys):
            rows = [c for c in art.criteria if c.key == key and c.value is not None]
            ax.bar([i + 0.4 * j for i in range(len(rows))], [c.value * 1e3 for c in rows], 0.4, label=key)
            ax.set_xticks(range(len(rows)), [c.target.replace("iso9283-", "") for c in rows])
        ax.set_ylabel("mm")
        ax.set_title(title)
        ax.legend()
    fig.suptitle(f"ISO 9283 — {art.robot}")
    return plotting.save_figure(fig, out, dpi=110)


def _cycle_log(what: str) -> Any:
    """A repeatable `--NAME-log` option: run logs of one cycle each of a test path."""
    return Annotated[
        list[Path] | None, typer.Option(help=f"Run log of one cycle of the {what} (repeatable).")
    ]


LineLog = _cycle_log("ISO line")
CircleLog = _cycle_log("large circle")
SmallCircleLog = _cycle_log("small circle")
RectangleLog = _cycle_log("rectangle")


def command(
    robot: RobotDir,
    output: Annotated[Path, typer.Option("-o", "--output", help="The criteria YAML.")] = Path("iso9283.yaml"),
    pose_log: Annotated[
        list[Path] | None,
        typer.Option("--pose-log", help="Pose-cycle run log with tracker data (repeatable)."),
    ] = None,
    line_log: LineLog = None,
    circle_log: CircleLog = None,
    small_circle_log: SmallCircleLog = None,
    rectangle_log: RectangleLog = None,
    paths: Iso9283Paths = None,
    calibration: Annotated[
        Path | None,
        typer.Option("--calibration", help="calibration.yaml: the base frame in the tracker frame."),
    ] = None,
    cell: Annotated[Path | None, CELL] = None,
    plot: Annotated[bool, typer.Option("--plot", help="Write NAME.png beside the output.")] = False,
) -> None:
    """ISO 9283 criteria (AP/RP at P1–P5, AT/RT/AV/RV on the paths, CO on the rectangle) from run logs
    with tracker data; criteria without a log are "not measured". Exit 2 on bad input. The base frame in
    the tracker frame: --calibration's, else --cell's nominal layout.

    Example: rxcomm iso9283 --robot samples/rx130l --calibration calibration.yaml --pose-log poses.mcap
    --line-log line.mcap -o iso9283.yaml"""
    console.stage_command(execute)(
        robot,
        output,
        pose_logs=list(pose_log or []),
        path_logs={
            target: list(logs or [])
            for target, logs in zip(
                LOG_OPTIONS, (line_log, circle_log, small_circle_log, rectangle_log), strict=True
            )
        },
        paths_dir=paths,
        calibration=calibration,
        cell=cell,
        plot=plot,
    )
