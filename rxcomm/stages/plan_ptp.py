"""`rxcomm plan-ptp`: time/energy-optimal point-to-point motion (paper §5.4–5.5, architecture §7).

Reads the robot (and optionally identified dynamics and a calibration), solves the free-final-time
OCP of `rxcomm.planning.ptp` between two rest states and writes the trajectory artefact `run` executes:
``NAME.mcap`` (q, q̇, q̈, τ_ff at the drive cycle) with ``NAME.yaml`` beside it (architecture §9 summary).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, get_args

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.files import trajectory_output
from rxcomm.io.validate import settings_from_options
from rxcomm.options import (
    POSE_PREFIX,
    TRAJECTORY_OUTPUT,
    Objective,
    PlanDuration,
    RobotDir,
    TimeWeight,
    Timing,
    parse_numbers,
    radians_text,
)
from rxcomm.schemas.path import Branch
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS
from rxcomm.stages.stage_cli import stage
from rxcomm.stages.summary import motion_summary, planned_energy

if TYPE_CHECKING:
    from rxcomm.model.robot import Robot
    from rxcomm.planning.ptp import PtpResult
    from rxcomm.planning.ptp_problem import PtpDynamics, PtpLimits, PtpOptions


# --- inputs -----------------------------------------------------------------------------------------
def state_text(rad: str | None, deg: str | None, option: str) -> str:
    """The radian text of the required pair `--OPTION` / `--OPTION-deg`."""
    text = radians_text(rad, deg, option)
    if text is None:
        raise InputError(f"give --{option} (rad) or --{option}-deg", field=option)
    return text


def parse_state(
    robot: Robot, text: str, field: str, branch: Branch, near: np.ndarray | None = None
) -> tuple[np.ndarray, str]:
    """A joint state `q1,…,qn` (rad) or a TCP pose `pose:x,y,z,α,β,γ`; returns (q, "joints"|"pose")."""
    from rxcomm.model.kinematics import solve_pose_ik

    text = text.strip()
    if text.lower().startswith(POSE_PREFIX):
        pose = parse_numbers(text[len(POSE_PREFIX) :], 6, field)
        return solve_pose_ik(robot, pose, branch, field, near), "pose"
    return parse_numbers(text, robot.n, field), "joints"


def parse_box(text: str | None) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    if text is None:
        return None
    v = parse_numbers(text, 6, "tcp-box")
    if not np.all(v[:3] < v[3:]):
        raise InputError(f"min corner {v[:3].tolist()} must be below max {v[3:].tolist()}", field="tcp-box-m")
    return tuple(v[:3]), tuple(v[3:])


# --- outputs ----------------------------------------------------------------------------------------
def summary_of(result: PtpResult, q_start, q_goal, margin: float) -> dict[str, object]:
    rep, sol = result.report, result.solution
    limit, joint, t_worst, _ = rep.worst()
    out: dict[str, object] = {
        "duration_s": result.duration_s,
        "solve_seconds": sol.solve_seconds,
        "max_limit_ratio": result.max_limit_ratio,
        "active_fraction": result.active_fraction(),
        "q_start": np.asarray(q_start).tolist(),
        "q_goal": np.asarray(q_goal).tolist(),
        "build_seconds": result.build_seconds,
        "iterations": sol.iterations,
        "solver_status": sol.status,
        "objective": sol.objective,
        "tau_squared_integral_nm2_s": result.tau_squared_integral,
        "warm_start_duration_s": result.warm_start.duration_s,
        "worst_limit": f"{limit} {joint} at {t_worst:.4f} s",
        # what max_limit_ratio covers (the torque rate as `run` checks it, ptp module doc)
        "limits_checked": ", ".join(rep.ratios) + (", tcp_box" if result.tcp_box_ratio is not None else ""),
        "fallback": False,
        "resolves": result.resolves,
    }
    out |= {f"max_{k}_ratio": v for k, v in rep.max_by_limit().items()}
    # the limits whose margin the re-solves widened beyond the option's
    out |= {f"margin_{k}": v for k, v in (result.margins or {}).items() if v > margin}
    if result.tcp_box_ratio is not None:
        out["max_tcp_box_ratio"] = result.tcp_box_ratio
    return out


def plot_ptp(result: PtpResult, limits: PtpLimits, joint_names, path: Path, title: str) -> Path:
    """PNG, one row per limit the motion obeys (the paper's Fig. 9 has torque and velocity): each joint's
    value / limit within ±1, the binding ones (≥ plotting.BINDS of the bound) in colour, the others
    faded, so the limit that sets the duration (often acceleration) stands out."""
    plt = plotting.pyplot()

    traj, rep = result.trajectory, result.report
    # the dense report is on the trajectory's own samples
    raw = plotting.joint_signs(
        traj.t, traj.q, traj.qd, traj.qdd, traj.tau_ff, (limits.q_min + limits.q_max) / 2
    )
    ratios = plotting.signed_ratios(rep.ratios, raw)
    names = [k for k in ("position", "velocity", "acceleration", "torque", "torque_rate") if k in ratios]
    names += [k for k in ratios if k not in names]
    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(10, 1.9 * len(names) + 0.8), squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        cols = list(joint_names) if ratios[name].shape[1] == len(joint_names) else ["TCP"]
        plotting.limit_panel(ax, rep.t, {name: ratios[name]}, cols, what=name.replace("_", " ") + " / limit")
    axes[-1, 0].set_xlabel("t [s]")
    fig.suptitle(title)
    return plotting.save_figure(fig, path, dpi=110)


# --- the stage --------------------------------------------------------------------------------------
def _branch_choice(field: str) -> object:
    """The values of a `Branch` field (its Literal without None), the choices of its option."""
    return next(a for a in get_args(Branch.model_fields[field].annotation) if a is not type(None))


Shoulder, Elbow, Wrist = (_branch_choice(f) for f in ("shoulder", "elbow", "wrist"))

# The options, named here so that `command` reads as a list.
StartOption = Annotated[
    str | None,
    typer.Option(
        help="Start at rest: joint angles 'q1,…,q6' (rad) or a TCP pose 'pose:x,y,z,α,β,γ' "
        "(m; Cardan x-y-z angles in rad; base frame). This or --start-deg is required."
    ),
]
StartDegOption = Annotated[
    str | None, typer.Option(help="As --start with every angle in degrees (poses: m and deg).")
]
GoalOption = Annotated[str | None, typer.Option(help="Goal at rest, as --start.")]
GoalDegOption = Annotated[str | None, typer.Option(help="Goal at rest, as --start-deg.")]
CalibrationOption = Annotated[
    Path | None,
    typer.Option(
        help="calibration.yaml: IK of poses and the TCP box on the calibrated robot "
        "(torques stay on the robot's own, as run computes them)."
    ),
]
EnergyWeightOption = Annotated[float, typer.Option(help="Weight of τᵀτ in ∫(k1 + k2·τᵀτ)dt, 1/(N·m)².")]
IntervalsOption = Annotated[
    int, typer.Option("--time-intervals", help="Jerk intervals of the OCP time grid.")
]
MarginOption = Annotated[
    float, typer.Option("--margin-fraction", help="Limits tightened by this fraction in the NLP.")
]
AccelerationLimitsOption = Annotated[
    bool,
    typer.Option(
        help="Limit joint accelerations to drives.yaml, as `run` checks. --no-acceleration-limits "
        "solves the paper's problem (torque, torque rate, velocity, position only), which `run` refuses."
    ),
]
TcpBoxOption = Annotated[
    str | None,
    typer.Option("--tcp-box-m", help="Keep the TCP in 'xmin,ymin,zmin,xmax,ymax,zmax' (m, base frame)."),
]
ShoulderOption = Annotated[Shoulder, typer.Option(help="IK branch for poses: shoulder.")]
ElbowOption = Annotated[Elbow, typer.Option(help="IK branch for poses: elbow.")]
WristOption = Annotated[Wrist, typer.Option(help="IK branch for poses: sign of J5.")]
MaxWallOption = Annotated[float | None, typer.Option("--max-wall-s", help="Solver wall-time cap, s.")]
CompileOption = Annotated[
    bool | None,
    typer.Option(
        "--compile/--no-compile",
        help="The NLP's node functions as C (needs gcc/cc; cached in ~/.cache/rxcomm, or "
        "$RXCOMM_CACHE_DIR). Default: compiled unoptimised (~1 s once, ~2× faster solves); --compile "
        "optimised (~1 min once, ~10 % faster again); --no-compile: CasADi's virtual machine.",
    ),
]
FallbackOption = Annotated[
    bool, typer.Option(help="If the solver fails, write the fastest feasible ruckig profile (still exit 3).")
]
PlotOption = Annotated[bool, typer.Option(help="Write NAME.png: normalised torques and velocities.")]
TimingOption = Annotated[
    Timing, typer.Option(help="optimal: the OCP; catalogue: the factory's ruckig profile (model.catalogue).")
]


@stage("plan-ptp")
def command(
    robot_dir: RobotDir,
    output: Annotated[Path, TRAJECTORY_OUTPUT],
    start: StartOption = None,
    start_deg: StartDegOption = None,
    goal: GoalOption = None,
    goal_deg: GoalDegOption = None,
    dynamics: Path | None = None,
    payload: Path | None = None,
    calibration: CalibrationOption = None,
    k1: TimeWeight = 1.0,
    k2: EnergyWeightOption = 0.0,
    objective: Objective = "torque",
    duration_s: PlanDuration = None,
    intervals: IntervalsOption = 50,
    margin: MarginOption = 0.01,
    acceleration_limits: AccelerationLimitsOption = True,
    tcp_box: TcpBoxOption = None,
    shoulder: ShoulderOption = "front",
    elbow: ElbowOption = "up",
    wrist: WristOption = "positive",
    max_wall: MaxWallOption = None,
    compile_: CompileOption = None,
    fallback: FallbackOption = False,
    plot: PlotOption = False,
    timing: TimingOption = "optimal",
) -> dict[str, object]:
    """Plan the time/energy-optimal rest-to-rest motion between two joint states or TCP poses."""
    from rxcomm.model.payload import model_name

    start, goal = state_text(start, start_deg, "start"), state_text(goal, goal_deg, "goal")
    t_all, output = time.perf_counter(), trajectory_output(output)
    DECLARATIONS["plan-ptp"].check(
        output=output, plot=plot, robot=robot_dir, dynamics=dynamics, payload=payload, calibration=calibration
    )
    robot, dyn, inputs = _planning_model(robot_dir, calibration, dynamics, payload)
    given = dict(n_intervals=intervals, k1=k1, k2_per_nm2=k2, margin=margin, tcp_box_m=parse_box(tcp_box))
    given |= dict(acceleration_limits=acceleration_limits, max_wall_s=max_wall, compile=compile_)
    options = _options(robot, given | dict(objective=objective, duration_s=duration_s))
    branch = Branch(shoulder=shoulder, elbow=elbow, wrist=wrist)
    q_start, start_kind = parse_state(robot, start, "start", branch)
    q_goal, goal_kind = parse_state(robot, goal, "goal", branch, near=q_start)
    settings = {
        "start": start,
        "goal": goal,
        "start_kind": start_kind,
        "goal_kind": goal_kind,
        "branch": branch.model_dump(),
        "options": options.model_dump(mode="json"),
        "dynamics_model": model_name(dynamics, payload),
        "calibrated": calibration is not None,
        "timing": timing,
    }
    target = _Target(output, inputs, settings, t_all)
    if timing == "catalogue":
        return _write_catalogue(robot_dir, robot, dyn, q_start, q_goal, target)
    return _write_optimal(robot, dyn, q_start, q_goal, options, target, fallback=fallback, plot=plot)


def _options(robot: Robot, given: dict) -> PtpOptions:
    """The OCP's options from the command line's (the energy objective's bus model from drives.yaml)."""
    from rxcomm.model.energy import BusPowerModel
    from rxcomm.planning.ptp_problem import PtpOptions

    given["bus"] = BusPowerModel.of(robot) if given["objective"] == "energy" else None
    names = {"n_intervals": "intervals", "k2_per_nm2": "k2", "tcp_box_m": "tcp-box", "max_wall_s": "max-wall"}
    return settings_from_options(PtpOptions, given, names | {"bus": "objective", "duration_s": "duration-s"})


def _planning_model(
    robot_dir: Path, calibration: Path | None, dynamics: Path | None, payload: Path | None = None
) -> tuple[Robot, PtpDynamics, dict[str, Path]]:
    """The robot (calibrated if given), its PtP model and the input files. The torques are the
    identified parameters' (the prior's without), with the identified payload on the last link when
    given, on the kinematics they were fitted on, as `run` evaluates them (`load_dynamics`); the TCP
    kinematics are the calibrated robot's."""
    from rxcomm.calibration.loading import load_calibrated_robot
    from rxcomm.model.payload import model_inputs, model_parameters
    from rxcomm.model.robot import load_robot
    from rxcomm.planning.ptp_problem import PtpDynamics

    nominal = robot = load_robot(robot_dir)
    inputs: dict[str, Path] = {"urdf": robot.urdf_path, "drives": robot.drives_path}
    if calibration is not None:
        robot = load_calibrated_robot(robot, calibration)
        inputs["calibration"] = Path(calibration)
    params, fitted = model_parameters(nominal, dynamics, payload)  # None: the prior
    inputs |= model_inputs(dynamics, payload)
    return robot, PtpDynamics.from_parameters(fitted, params, kinematics=robot), inputs


@dataclass(frozen=True)
class _Target:
    """Where a plan is written and what its envelope records beside the samples."""

    output: Path  # NAME.mcap (NAME.yaml beside it)
    inputs: dict[str, Path]
    settings: dict[str, object]
    t_all: float  # time.perf_counter() when the stage started

    def save(
        self, traj, summary: dict[str, object], joint_names=None, robot=None, **settings: object
    ) -> None:
        """The MCAP and its summary YAML (with `robot`, the plan's 3D view); `settings` adds to the
        recorded settings."""
        from rxcomm.execution.plan_views import plan_views
        from rxcomm.io.trajectory import save_trajectory_mcap

        env = TrajectorySummary.envelope(self.inputs, {**self.settings, **settings}, summary)
        self.output.parent.mkdir(parents=True, exist_ok=True)
        views = None if robot is None else plan_views(robot)
        save_trajectory_mcap(self.output, traj, env, joint_names, views)


def _write_optimal(robot, dyn, q_start, q_goal, options, target: _Target, *, fallback: bool, plot: bool):
    """The OCP's optimum (or, if it fails and `fallback`, the kinematic profile before exit 3)."""
    from rxcomm.planning.ptp import PtpNotConverged, plan_ptp, quadrature_energy
    from rxcomm.planning.ptp_problem import PtpLimits

    with console.phase(f"plan-ptp: solving the OCP (N = {options.n_intervals})"):
        try:
            result = plan_ptp(robot, dyn, q_start, q_goal, options)
        except PtpNotConverged as e:
            if fallback:
                _write_fallback(robot, dyn, q_start, q_goal, options, target, e)
            raise
    summary = summary_of(result, q_start, q_goal, options.margin)
    bus = options.bus  # the energy objective's own figure beside the drive-cycle samples' energy
    summary |= planned_energy(robot, result.trajectory, bus and quadrature_energy(result.solution, dyn, bus))
    summary["seconds"] = time.perf_counter() - target.t_all
    target.save(result.trajectory, summary, robot.joint_names, robot)
    if plot:
        limits = PtpLimits.from_robot(robot, acceleration=options.acceleration_limits)
        title = f"PtP {result.duration_s:.3f} s (k1 = {options.k1:g}, k2 = {options.k2_per_nm2:g}): "
        title += "every limit, value / limit"
        png = plot_ptp(result, limits, robot.joint_names, target.output.with_suffix(".png"), title)
        console.out.print(f"plot: {png}")
    console.summary_table(f"plan-ptp → {target.output}", summary)
    return summary


def _write_catalogue(robot_dir, robot, dyn, q_start, q_goal, target: _Target) -> dict:
    """The factory's move: the catalogue limits of the nominal prior robot, ruckig's profile."""
    from rxcomm.model.catalogue import catalogue_limits
    from rxcomm.model.robot import load_robot
    from rxcomm.planning.catalogue_timing import plan_ptp_catalogue

    catalogue = catalogue_limits(load_robot(robot_dir))
    t0 = time.perf_counter()
    traj, report = plan_ptp_catalogue(robot, dyn, q_start, q_goal, catalogue)
    limit, joint, t_worst, _ = report.worst()
    summary = motion_summary(traj.duration_s, time.perf_counter() - t0, report, q_start, q_goal)
    summary |= {
        "tau_squared_integral_nm2_s": float(np.trapezoid(np.sum(traj.tau_ff**2, axis=1), traj.t)),
        "worst_limit": f"{limit} {joint} at {t_worst:.4f} s",
        "limits_checked": ", ".join(report.ratios),
        "fallback": False,
        "catalogue_acceleration_bound": catalogue.binding_text(),
        **{f"max_{k}_ratio": v for k, v in report.max_by_limit().items()},
        "seconds": time.perf_counter() - target.t_all,
    }
    target.save(traj, summary, robot.joint_names, robot, catalogue=catalogue.as_dict())
    console.summary_table(f"plan-ptp (catalogue timing) → {target.output}", summary)
    return summary


def _write_fallback(robot, dyn, q_start, q_goal, options, target: _Target, error) -> None:
    from rxcomm.planning.ptp import kinematic_fallback

    traj, report = kinematic_fallback(robot, dyn, q_start, q_goal, options)
    summary = motion_summary(traj.duration_s, error.solution.solve_seconds, report, q_start, q_goal)
    summary |= {"solver_status": error.status, "fallback": True}
    target.save(traj, summary, robot.joint_names, robot)
    console.err.print(
        f"[yellow]fallback[/]: wrote the kinematic (ruckig) profile, {traj.duration_s:.3f} s, "
        f"max limit ratio {report.max_ratio:.3f}, to {target.output}"
    )
