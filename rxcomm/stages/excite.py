"""`rxcomm excite`: an optimal exciting trajectory for dynamic identification (paper §4.2, architecture §7).

Reads the robot and the cell (its `allowed_region` for tool, wrist centre and elbow), designs the
rest-to-rest Fourier trajectory of `rxcomm.identification.excitation` and writes

- ``excitation.yaml`` (kind rxcomm/Excitation): coefficients, rest pose, ω_f, per-start results, the
  drive-cycle limit ratios and the architecture §9 summary (cond, cond_raw, baseline_cond, duration_s,
  seconds, max_limit_ratio);
- the trajectory `run` executes beside it, ``excitation-trajectory.mcap`` + ``.yaml`` (kind
  rxcomm/Trajectory: q, q̇, q̈ and τ_ff from the prior model at the drive cycle);
- with ``--plot``, ``excitation.png``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.validate import settings_from_options
from rxcomm.io.yaml_io import read_yaml_model, write_yaml_artefact
from rxcomm.options import CELL, OBJECTIVE_HELP, RobotDir, parse_numbers, radians_text, radians_value
from rxcomm.schemas.cell import AllowedRegion, Cell
from rxcomm.schemas.excitation import Excitation, ExcitationSettings, ExcitationStart
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS

if TYPE_CHECKING:
    from rxcomm.identification.excitation import ExcitationDesign
    from rxcomm.model.robot import Robot


Objective = Literal["cond", "logdet"]


def trajectory_path(output: Path) -> Path:
    """``excitation.yaml`` -> ``excitation-trajectory.mcap`` (its own ``.yaml`` must not clash)."""
    return DECLARATIONS["excite"].written(output=output)["trajectory-out"]


def design_ratios(robot: Robot, s, opts: ExcitationSettings, region: AllowedRegion | None) -> dict:
    """Signed (value − centre) / half-width of every constraint the design obeyed (ExcitationProblem's
    limits: joint ranges minus the margin, the velocity, acceleration and torque fractions of the
    robot's limits, the torque rate, the allowed-region boxes minus their margin): ±1 is the bound."""
    from rxcomm.identification.excitation_limits import REGION_POINTS, region_points
    from rxcomm.model.limits import TorqueRateLimit

    q_lo, q_hi = robot.q_min + opts.position_margin_rad, robot.q_max - opts.position_margin_rad
    out = {
        "position": (s.q - (q_lo + q_hi) / 2) / ((q_hi - q_lo) / 2),
        "velocity": s.qd / (opts.velocity_fraction * robot.v_max),
        "acceleration": s.qdd / (opts.acceleration_fraction * robot.a_max),
        "torque": s.tau_ff / (opts.torque_fraction * robot.tau_max),
    }
    rate = TorqueRateLimit(robot.tau_rate_max).ratios(s.t, s.q, s.qd, s.qdd, s.tau_ff)
    out["torque_rate"] = plotting.signed_ratios({"r": rate}, {"r": np.gradient(s.tau_ff, s.t, axis=0)})["r"]
    if region is not None:
        pts = region_points(robot, s.q)
        for name in REGION_POINTS:
            box = getattr(region, name)
            lo, hi = np.asarray(box.min_m), np.asarray(box.max_m)
            out[f"region {name}"] = (pts[name] - (lo + hi) / 2) / ((hi - lo) / 2 - opts.region_margin_m)
    return out


def plot_excitation(
    robot: Robot, design: ExcitationDesign, opts: ExcitationSettings, region: AllowedRegion | None, path: Path
) -> Path:
    """PNG: joint positions, then every constraint the design obeyed normalised to its bound (the
    0.8·peak torque actually used, not the peak; the allowed-region boxes), the binding ones (≥
    plotting.BINDS) in colour and the others faded, and the tool path (paper Fig. 5a)."""
    from rxcomm.identification.excitation_limits import region_points

    plt = plotting.pyplot()

    k = max(1, len(design.samples.t) // 3000)
    s = design.samples
    sub = type(s)(s.t[::k], s.q[::k], s.qd[::k], s.qdd[::k], s.tau_ff[::k])
    ratios = design_ratios(robot, sub, opts, region)
    fig = plt.figure(figsize=(14, 2.1 * 4 + 1.0))
    grid = fig.add_gridspec(4, 2)
    names = list(robot.joint_names)
    left = ["position", "velocity", "acceleration", "torque"]
    units = {
        "velocity": f"{opts.velocity_fraction:g}·q̇_max",
        "acceleration": f"{opts.acceleration_fraction:g}·q̈_max",
    }
    units |= {"torque": f"{opts.torque_fraction:g}·τ_peak, prior", "position": "range − margin"}
    for i, name in enumerate(left):
        ax = fig.add_subplot(grid[i, 0])
        plotting.limit_panel(ax, sub.t, {name: ratios[name]}, names, what=f"{name} / ({units[name]})")
    ax = fig.add_subplot(grid[0, 1])
    plotting.limit_panel(ax, sub.t, {"torque_rate": ratios["torque_rate"]}, names, what="torque rate / limit")
    ax = fig.add_subplot(grid[1, 1])
    regions = {k: v for k, v in ratios.items() if k.startswith("region")}
    if regions:
        plotting.limit_panel(ax, sub.t, regions, ["x", "y", "z"], what="region / (box − margin)")
    else:
        ax.text(0.5, 0.5, "no allowed region in the cell", ha="center", va="center", transform=ax.transAxes)
    for ax in fig.axes:
        ax.set_xlabel("t [s]")
    ax3 = fig.add_subplot(grid[2:, 1], projection="3d")
    pts = region_points(robot, s.q[:: max(1, len(s.t) // 800)])["tool"]
    ax3.plot(pts[:, 0], pts[:, 1], pts[:, 2], lw=0.8)
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    ax3.set_title("tool path")
    fig.suptitle(
        f"excitation: cond {design.cond:.2f} (random feasible {design.baseline_cond:.0f}), "
        f"{design.samples.duration_s:.2f} s; every constraint as value / the bound the design obeyed"
    )
    return plotting.save_figure(fig, path, dpi=100)


# The options whose help runs over several lines, named here so that `command` reads as a list.
CellOption = Annotated[Path, CELL]  # its allowed_region bounds tool, wrist centre, elbow
TrajectoryOutOption = Annotated[
    Path | None,
    typer.Option(help="Trajectory MCAP for `run` (default: OUTPUT's stem + '-trajectory.mcap')."),
]
OmegaOption = Annotated[float, typer.Option("--omega-rad-s", help="Base frequency ω_f, rad/s (paper: 0.8).")]
ObjectiveOption = Annotated[Objective, typer.Option(help=OBJECTIVE_HELP)]
PositionMarginOption = Annotated[
    float | None,
    typer.Option("--position-margin-rad", help="Kept from each joint limit, rad (default 0.05)."),
]
PositionMarginDegOption = Annotated[
    float | None, typer.Option("--position-margin-deg", help="Kept from each joint limit, degrees.")
]
BaselineOption = Annotated[
    int, typer.Option(help="Random feasible trajectories whose median cond is the baseline.")
]
StartOption = Annotated[
    str | None, typer.Option(help="Fixed rest pose 'q1,…,q6' (rad); optimised when not given.")
]


@console.stage_command
def command(
    robot_dir: RobotDir,
    cell: CellOption,
    output: Annotated[Path, typer.Option("-o", "--output", help="Output excitation.yaml.")],
    trajectory_out: TrajectoryOutOption = None,
    harmonics: Annotated[int, typer.Option(help="Fourier harmonics per joint (paper: 5).")] = 5,
    omega: OmegaOption = 0.8,
    samples: Annotated[int, typer.Option(help="Objective samples per period k (paper: 80).")] = 80,
    periods: Annotated[int, typer.Option(help="Periods in the executed trajectory.")] = 1,
    starts: Annotated[int, typer.Option(help="Seeded random feasible starts; the best is kept.")] = 4,
    seed: Annotated[int, typer.Option(help="Seed of the random starts and baseline.")] = 0,
    objective: ObjectiveOption = "cond",
    torque_fraction: Annotated[float, typer.Option(help="Of peak torque, prior model.")] = 0.8,
    velocity_fraction: Annotated[float, typer.Option(help="Of the velocity limits.")] = 0.95,
    acceleration_fraction: Annotated[float, typer.Option(help="Of the acceleration limits.")] = 0.95,
    position_margin: PositionMarginOption = None,
    position_margin_deg: PositionMarginDegOption = None,
    max_iterations: Annotated[int, typer.Option(help="SLSQP iterations per start.")] = 150,
    baseline_trajectories: BaselineOption = 10,
    start: StartOption = None,
    start_deg: Annotated[str | None, typer.Option(help="Fixed rest pose 'q1,…,q6' in degrees.")] = None,
    plot: Annotated[bool, typer.Option(help="Write OUTPUT.png: trajectory and tool path.")] = False,
) -> Excitation:
    """Design the optimal exciting trajectory (min cond of the base regressor) within every limit.

    --cell: its allowed_region bounds tool, wrist centre and elbow."""
    from rxcomm.model.robot import load_robot

    start = radians_text(start, start_deg, "start")
    values = {
        "harmonics": harmonics,
        "omega_f_rad_s": omega,
        "objective_samples": samples,
        "periods": periods,
        "starts": starts,
        "seed": seed,
        "objective": objective,
        "torque_fraction": torque_fraction,
        "velocity_fraction": velocity_fraction,
        "acceleration_fraction": acceleration_fraction,
        "position_margin_rad": radians_value(position_margin, position_margin_deg, "position-margin", 0.05),
        "max_iterations": max_iterations,
        "baseline_trajectories": baseline_trajectories,
    }
    output, traj_path = _outputs(output, trajectory_out)
    DECLARATIONS["excite"].check(
        output=output, trajectory_out=traj_path, plot=plot, robot=robot_dir, cell=cell
    )
    robot = load_robot(robot_dir)
    cell_model = read_yaml_model(cell, Cell)
    if start is not None:
        values["start_rad"] = parse_numbers(start, robot.n, "start", "rad").tolist()
    opts = settings_from_options(ExcitationSettings, values)
    design = _design(robot, cell_model.allowed_region, opts)
    inputs = {"urdf": robot.urdf_path, "drives": robot.drives_path, "cell": Path(cell)}
    art, summary = _write(robot, design, opts, inputs, output, traj_path)
    if plot:
        png = plot_excitation(robot, design, opts, cell_model.allowed_region, output.with_suffix(".png"))
        console.out.print(f"plot: {png}")
    console.summary_table(f"excite → {output} (+ {traj_path.name})", summary)
    return art


def _outputs(output: Path, trajectory_out: Path | None) -> tuple[Path, Path]:
    """excitation.yaml and the trajectory MCAP beside it (or where `--trajectory-out` says)."""
    output = Path(output)
    if output.suffix not in (".yaml", ".yml"):
        raise InputError("the output must be a .yaml file", field="output")
    traj_path = Path(trajectory_out) if trajectory_out is not None else trajectory_path(output)
    if traj_path.suffix != ".mcap":
        raise InputError("the trajectory output must be NAME.mcap", field="trajectory-out")
    return output, traj_path


def _design(robot: Robot, region: AllowedRegion | None, opts: ExcitationSettings) -> ExcitationDesign:
    """`design_excitation` with a progress bar per phase."""
    from rxcomm.identification.excitation import design_excitation

    with console.progress() as bar:
        tasks: dict[str, int] = {}

        def progress(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(f"excite: {stage}", total=total)
            bar.update(tasks[stage], completed=done)

        return design_excitation(robot, region, opts, progress=progress)


def _write(
    robot, design, opts, inputs: dict[str, Path], output: Path, traj_path: Path
) -> tuple[Excitation, dict]:
    """The trajectory MCAP (+ its YAML) `run` executes and excitation.yaml; returns the artefact and
    its summary."""
    from rxcomm.io.trajectory import save_trajectory_mcap
    from rxcomm.model.limits import check_limits

    samples = design.samples
    report = check_limits(robot, samples.t, samples.q, samples.qd, samples.qdd, samples.tau_ff)
    traj_summary = {
        "duration_s": samples.duration_s,
        "solve_seconds": design.seconds,
        "max_limit_ratio": design.max_limit_ratio,
        "active_fraction": report.active_fraction(),
        "q_start": samples.q[0].tolist(),
        "q_goal": samples.q[-1].tolist(),
        "cond": design.cond,
    }
    output.parent.mkdir(parents=True, exist_ok=True)
    traj_path.parent.mkdir(parents=True, exist_ok=True)
    env = TrajectorySummary.envelope(inputs, opts, traj_summary)
    from rxcomm.execution.plan_views import plan_views

    save_trajectory_mcap(traj_path, samples, env, robot.joint_names, plan_views(robot))
    summary = design_summary(design)
    art = excitation_artefact(
        robot, design, opts.periods, Excitation.envelope(inputs, opts, summary), traj_path, output
    )
    write_yaml_artefact(output, art)
    return art, summary


def design_summary(design: ExcitationDesign) -> dict[str, object]:
    """The summary of excitation.yaml: conditioning beside the random baseline, limits, timing."""
    return {
        "cond": design.cond,
        "cond_raw": design.cond_raw,
        "baseline_cond": design.baseline_cond,
        "duration_s": design.samples.duration_s,
        "seconds": design.seconds,
        "max_limit_ratio": design.max_limit_ratio,
        "cond_dense": design.cond_dense,
        "improvement_ratio": design.baseline_cond / design.cond,
        "worst_limit": f"{design.worst_limit[0]} {design.worst_limit[1]} at {design.worst_limit[2]:.3f} s",
        "n_base_params": design.bset.n_base,
        "starts_feasible": sum(s.feasible for s in design.starts),
    }


def excitation_artefact(
    robot: Robot, design: ExcitationDesign, periods: int, envelope: dict, traj_path: Path, output: Path
) -> Excitation:
    """excitation.yaml's artefact: the coefficients, the starts, the limit ratios and the trajectory
    file (by name when it lies beside the output)."""
    traj = design.trajectory
    return Excitation(
        **envelope,
        robot=robot.name,
        robot_joints=list(robot.joint_names),
        harmonics=traj.harmonics,
        omega_f_rad_s=traj.omega_rad_s,
        period_s=traj.period_s,
        periods=periods,
        q0_rad=traj.q0.tolist(),
        q_start_rad=traj.q_start.tolist(),
        a_rad_s=traj.a.tolist(),
        b_rad_s=traj.b.tolist(),
        base_parameters=list(design.bset.names),
        starts=[ExcitationStart.model_validate(s, from_attributes=True) for s in design.starts],
        limit_ratios=design.limit_ratios,
        trajectory_file=traj_path.name
        if traj_path.parent.resolve() == output.parent.resolve()
        else str(traj_path),
        trajectory_sha256=sha256_file(traj_path),
    )
