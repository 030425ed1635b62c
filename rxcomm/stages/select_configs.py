"""`rxcomm select-configs`: optimal measurement poses for calibration (paper §3.3, architecture §7).

Reads the robot and the cell, streams the joint grid through the cell checks, runs the exchange
algorithm of `rxcomm.calibration.pose_selection` and writes `configs.yaml` (kind `rxcomm/Configs`): the
selected `fit` poses, then `validation` poses for calibrate to hold out (and, with
`--measure-baseline`, the naive set's poses to measure as well), the index, the naive baseline's
index (the paper's linear scan) and their ratio, the same for evenly spaced candidates, and the rms
prediction error each set should leave after calibration at the tracker noise of `cell.yaml`.
`--plot` writes NAME.png with the poses.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.options import CELL, RobotDir
from rxcomm.stages.declarations import DECLARATIONS

if TYPE_CHECKING:  # the library (pinocchio, scipy) is imported where used: `--help` stays fast
    from rxcomm.calibration.pose_selection import PoseSelection
    from rxcomm.model.robot import Robot
    from rxcomm.schemas.cell import Cell
    from rxcomm.schemas.configs import Configs


def read_cell(path: Path) -> Cell:
    from rxcomm.io.yaml_io import read_yaml_model
    from rxcomm.schemas.cell import Cell

    return read_yaml_model(path, Cell)


def configs_artefact(
    robot: Robot,
    sel: PoseSelection,
    inputs: dict[str, Path],
    settings: dict,
    seconds: float,
    measure_baseline: bool = False,
) -> Configs:
    from rxcomm.model.geometric_errors import predict_poses
    from rxcomm.schemas.configs import ConfigPose, Configs

    parts = [("fit", sel.q_selected), ("validation", sel.q_validation)]
    if measure_baseline:
        parts.append(("baseline", sel.baseline.q))
    q_all = np.vstack([q for _, q in parts])
    tcp, _ = predict_poses(robot, q_all)
    roles = [role for role, q in parts for _ in range(len(q))]
    poses = [
        ConfigPose(q_rad=q.tolist(), role=r, tcp_position_m=tuple(p))
        for q, r, p in zip(q_all, roles, tcp, strict=True)
    ]
    cand = sel.candidates
    summary = {
        "n_candidates": int(cand.q.shape[0]),
        "n_selected": int(len(sel.q_selected)),
        "observation_index": sel.selection.observation_index,
        "baseline_observation_index": sel.baseline.observation_index,
        "improvement_ratio": sel.baseline.improvement_ratio,
        "min_eig_improvement_ratio": sel.min_eig_improvement_ratio,
        "expected_position_error_m": sel.expected_error[0],
        "baseline_expected_position_error_m": sel.baseline.expected_error[0],
        "evenly_spaced_expected_position_error_m": sel.evenly_spaced.expected_error[0],
        "expected_orientation_error_rad": sel.expected_error[1],
        "baseline_expected_orientation_error_rad": sel.baseline.expected_error[1],
        "evenly_spaced_expected_orientation_error_rad": sel.evenly_spaced.expected_error[1],
        "evenly_spaced_observation_index": sel.evenly_spaced.observation_index,
        "evenly_spaced_improvement_ratio": sel.evenly_spaced.improvement_ratio,
        "seconds": seconds,
        "n_baseline": int(len(sel.baseline.q)),
        "n_validation": int(len(sel.q_validation)),
        "n_grid": cand.n_grid,
        "n_feasible": cand.n_feasible,
        "n_identifiable": len(sel.identifiable),
        "restart_indices": list(sel.selection.restart_indices),
        "grid_seconds": cand.seconds,
        "selection_seconds": sel.selection.seconds,
    }
    summary |= {f"rejected_{k}": v for k, v in cand.rejected.items()}
    return Configs(
        **Configs.envelope(inputs, settings, summary),
        robot=robot.name,
        joint_names=list(robot.joint_names),
        criterion=settings["criterion"],
        measurement=sel.measurement,
        characteristic_length_m=sel.characteristic_length_m,
        identifiable=list(sel.identifiable.names),
        poses=poses,
        baseline_poses_rad=sel.baseline.q.tolist(),
        baseline_centre_rad=sel.scan.centre.tolist(),
        evenly_spaced_poses_rad=sel.evenly_spaced.q.tolist(),
    )


def plot_configs(robot: Robot, sel: PoseSelection, path: Path, title: str) -> Path:
    """PNG: the selected poses as stick figures (base frame) over the candidates' TCP cloud, the
    linear scan's TCPs beside them, and each joint's coverage by both sets."""
    from rxcomm.model.geometric_errors import _chain, predict_poses

    plt = plotting.pyplot()

    fig = plt.figure(figsize=(12, 5.5))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    cand_tcp, _ = predict_poses(robot, sel.candidates.q)
    ax.scatter(*cand_tcp.T, s=1, c="0.8", alpha=0.4, label="candidates (TCP)")
    ch = _chain(robot, sel.q_selected, None, None)
    for k in range(len(sel.q_selected)):
        pts = np.vstack([[0, 0, 0], ch.joint_frames[k, :, :3, 3], ch.tcp[k, :3, 3]])
        ax.plot(*pts.T, lw=1.0, color=plt.cm.viridis(k / max(len(sel.q_selected) - 1, 1)))
    ax.scatter(*ch.tcp[:, :3, 3].T, s=12, c="C3", label="selected (TCP)")
    scan_tcp, _ = predict_poses(robot, sel.baseline.q)
    ax.scatter(*scan_tcp.T, s=12, c="C0", marker="x", label="naive: linear scan (TCP)")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, 1.12), fontsize=8, ncol=3)  # above the box
    ax.set_title("selected poses")
    ax2 = fig.add_subplot(1, 2, 2)
    for j in range(robot.n):
        for q, dx, style in (
            (sel.q_selected, -0.12, {"c": "C3"}),
            (sel.baseline.q, 0.12, {"c": "C0", "marker": "x"}),
        ):
            ax2.scatter(
                np.full(len(q), j + 1 + dx) + np.linspace(-0.08, 0.08, len(q)),
                np.degrees(q[:, j]),
                s=10,
                label=None if j else ("selected" if dx < 0 else "linear scan"),
                **style,
            )
        ax2.plot([j + 1, j + 1], np.degrees([robot.q_min[j], robot.q_max[j]]), c="0.6", lw=6, alpha=0.4)
    ax2.set_xticks(range(1, robot.n + 1), robot.joint_names, fontsize=8)
    ax2.set_ylabel("joint angle [deg] (grey: range)")
    ax2.set_title("joint coverage")
    plotting.legend_outside(ax2)
    fig.suptitle(title)
    return plotting.save_figure(fig, path, dpi=110)


# The options whose help runs over several lines, named here so that `command` reads as a list.
CriterionName = Literal["min-eig", "det-root", "cond"]
IntervalsOption = Annotated[
    int, typer.Option("--grid-intervals", help="Joint-grid intervals per joint (midpoints; 13⁶ ≈ 4.8 M).")
]
MaxCandidatesOption = Annotated[
    int, typer.Option(help="Seeded uniform subset of the feasible grid poses to select from (0: all).")
]
CriterionOption = Annotated[
    CriterionName,
    typer.Option(
        help="Observation index: det-root det(Λ)^(1/p) (predicts best), min-eig σ_min(ΘᵀΘ) "
        "(the paper's), cond λ_max/λ_min."
    ),
]
ValidationPosesOption = Annotated[
    int,
    typer.Option(
        "--validation-poses",
        help="Extra random feasible poses to measure for validation (held out); as many as fit "
        "poses let one campaign tell two pose sets apart.",
    ),
]
MeasureBaselineOption = Annotated[
    bool,
    typer.Option(
        help="Also list the naive set (the linear scan) for run to measure, so calibrate reports "
        "the held-out error it would have left beside the selected set's (n more poses to measure)."
    ),
]


@console.stage_command
def command(
    robot_dir: RobotDir,
    cell: Annotated[Path, CELL],
    output: Annotated[Path, typer.Option("-o", "--output", help="Output configs.yaml.")],
    n: Annotated[int, typer.Option("--poses", help="Number of measurement poses to select.")] = 32,
    intervals: IntervalsOption = 13,
    max_candidates: MaxCandidatesOption = 4000,
    criterion: CriterionOption = "det-root",
    restarts: Annotated[int, typer.Option(help="Restarts of the exchange algorithm (best kept).")] = 5,
    n_validation: ValidationPosesOption = 32,
    seed: Annotated[int, typer.Option(help="Seed of the sub-sampling, starts and validation poses.")] = 0,
    measure_baseline: MeasureBaselineOption = False,
    plot: Annotated[bool, typer.Option(help="Write NAME.png with the selected poses.")] = False,
) -> dict[str, object]:
    """Select measurement poses that make the geometric error parameters well identifiable.

    --cell: its workspace, self-collision margins and tracker (field of view, noise)."""
    from rxcomm.calibration.pose_selection import Criterion
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.model.robot import load_robot

    t0 = time.perf_counter()
    output = Path(output)
    for value, name, lo in ((n, "poses", 1), (intervals, "grid-intervals", 1), (restarts, "restarts", 1)):
        if value < lo:
            raise InputError(f"must be ≥ {lo}, got {value}", field=name)
    if max_candidates < 0 or n_validation < 0:
        raise InputError("must be ≥ 0", field="max-candidates" if max_candidates < 0 else "validation-poses")
    DECLARATIONS["select-configs"].check(output=output, plot=plot, robot=robot_dir, cell=cell)
    robot = load_robot(robot_dir)
    cell_model = read_cell(cell)
    settings = {
        "n": n,
        "intervals": intervals,
        "max_candidates": max_candidates,
        "criterion": Criterion(criterion).value,
        "restarts": restarts,
        "n_validation": n_validation,
        "seed": seed,
        "measure_baseline": measure_baseline,
    }
    # the selection runs with the settings the artefact records (0 candidates: all of them)
    options = {k: v for k, v in settings.items() if k not in ("n", "measure_baseline")}
    sel = _select_with_progress(robot, cell_model, n, **options | {"max_candidates": max_candidates or None})
    seconds = time.perf_counter() - t0
    inputs = {"urdf": robot.urdf_path, "drives": robot.drives_path, "cell": Path(cell)}
    art = configs_artefact(robot, sel, inputs, settings, seconds, measure_baseline)
    output.parent.mkdir(parents=True, exist_ok=True)
    write_yaml_artefact(output, art)
    if plot:
        png = plot_configs(robot, sel, output.with_suffix(".png"), _plot_title(robot, sel, n, criterion))
        console.out.print(f"plot: {png}")
    console.summary_table(f"select-configs → {output}", art.summary)
    return art.summary


def _select_with_progress(robot: Robot, cell_model: Cell, n: int, **options) -> PoseSelection:
    """`select_measurement_poses` with a progress bar over the joint grid, then a phase while the
    exchange algorithm runs (it reports no fraction)."""
    from rxcomm.calibration.pose_selection import select_measurement_poses

    with console.progress() as bar:
        task = bar.add_task("select-configs: streaming the joint grid", total=options["intervals"] ** robot.n)
        selecting: list[int] = []

        def grid_progress(done: int, grid_total: int) -> None:
            bar.update(task, completed=done)
            if done >= grid_total and not selecting:
                what = f"select-configs: selecting {n} poses ({options['restarts']} restarts)"
                selecting.append(bar.add_task(what, total=None))

        return select_measurement_poses(robot, cell_model, n, progress=grid_progress, **options)


def _plot_title(robot: Robot, sel: PoseSelection, n: int, criterion: str) -> str:
    ratio = sel.baseline.improvement_ratio
    return (
        f"{robot.name}: {n} of {sel.candidates.q.shape[0]} candidates, {criterion} "
        f"{sel.selection.observation_index:.4g} (linear scan {sel.baseline.observation_index:.4g}"
        + (f", ×{ratio:.2f}" if ratio is not None else "")
        + f"; evenly spaced candidates {sel.evenly_spaced.observation_index:.4g})"
    )
