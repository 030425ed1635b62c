"""`rxcomm plan-cp`: time/energy-optimal timing of a Cartesian TCP path (paper §5.1–5.3, architecture §7).

Reads the robot, a path file (`rxcomm/Path`, `samples/ROBOT/paths/`), optionally identified dynamics
and a calibration; plans with `rxcomm.planning.cp.plan_cp` and writes the trajectory `run` executes:
``NAME.mcap`` (q, q̇, q̈, τ_ff, σ, σ̇ at the drive cycle) with ``NAME.yaml`` beside it (architecture §9
summary), and with ``--plot`` ``NAME.png`` (the paper's Figs. 7 and 8). With a ``--calibration`` that
found joint compliance, q is what the encoders must read to hold the links on the calibrated IK
(`rxcomm.calibration.compensation.compliance_command`, `rxcomm.planning.commanded`). The ISO 9283
test-plane paths are `rxcomm iso9283-paths` (``--iso9283 DIR``: its old spelling, hidden).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
import typer

from rxcomm import console, plotting
from rxcomm.errors import InputError
from rxcomm.io.files import trajectory_output
from rxcomm.io.validate import settings_from_options
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.options import TRAJECTORY_OUTPUT, Objective, PlanDuration, RobotDir, TimeWeight, Timing
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS
from rxcomm.stages.stage_cli import stage
from rxcomm.stages.summary import planned_energy

if TYPE_CHECKING:
    from rxcomm.io.trajectory import Trajectory
    from rxcomm.model.dynamics import DynamicParameters
    from rxcomm.model.robot import Robot
    from rxcomm.planning.cp import CpPlan


# --- outputs ----------------------------------------------------------------------------------------
def summary_of(plan: CpPlan, robot: Robot) -> dict[str, object]:
    from rxcomm.planning.cp import path_deviation_m

    rep = plan.report
    limit, joint, t_worst, _ = rep.worst()
    joint = "TCP" if limit.startswith("tcp") else joint
    sd = plan.sigma_dot
    n = len(sd)
    sm, sm_at = plan.joint_path.min_sigma_min
    out: dict[str, object] = {
        "duration_s": plan.duration_s,
        "solve_seconds": plan.timings_s["total_s"],
        "max_limit_ratio": rep.max_ratio,
        "active_fraction": plan.active_fraction,
        "q_start": plan.q[0].tolist(),
        "q_goal": plan.q[-1].tolist(),
        "method": plan.method,
        "path_length_m": plan.joint_path.length_m,
        "tau_squared_integral_nm2_s": plan.energy_nm2s,
        "max_tcp_speed_m_s": float(sd.max()),
        "min_tcp_speed_mid_m_s": float(sd[n // 4 : 3 * n // 4].min()) if n >= 4 else float(sd.min()),
        "singularity_margin": sm,
        "singularity_margin_at_m": sm_at,
        "max_path_deviation_m": path_deviation_m(robot, plan.joint_path),
        "toppra_duration_s": plan.toppra.profile.duration_s,
        "toppra_seconds": plan.timings_s["toppra_s"],
        "ik_seconds": plan.timings_s["ik_s"],
        "refinements": plan.refinements,
        "worst_limit": f"{limit} {joint} at {t_worst:.4f} s",
    }
    if plan.nlp is not None:
        out |= {
            "nlp_seconds": plan.timings_s["nlp_s"],
            "nlp_iterations": plan.nlp.iterations,
            "nlp_status": plan.nlp.status,
        }
    out |= {f"max_{k}_ratio": v for k, v in rep.max_by_limit().items()}
    return out


def trajectory_of(plan: CpPlan) -> Trajectory:
    from rxcomm.io.trajectory import Trajectory

    return Trajectory(
        plan.t, plan.q, plan.qd, plan.qdd, plan.tau, extra={"sigma": plan.sigma, "sigma_dot": plan.sigma_dot}
    )


def plot_cp(plan: CpPlan, robot: Robot, path: Path, title: str) -> Path:
    """PNG: TCP speed over time and σ (the paper's Fig. 7) and every limit normalised to ±1 over time
    (Fig. 8): the binding ones (≥ plotting.BINDS of the bound) in colour, the others faded, with the
    stretches where no limit is active shaded."""
    plt = plotting.pyplot()

    rep = plan.report
    fig, axes = plt.subplots(3, 1, figsize=(10, 8.5))
    axes[0].plot(plan.t, plan.sigma_dot)
    axes[0].set_xlabel("t [s]")
    axes[0].set_ylabel("TCP speed [m/s]")
    axes[1].plot(plan.sigma, plan.sigma_dot)
    axes[1].set_xlabel("σ (TCP arc length) [m]")
    axes[1].set_ylabel("TCP speed [m/s]")
    raw = plotting.joint_signs(plan.t, plan.q, plan.qd, plan.qdd, plan.tau, (robot.q_min + robot.q_max) / 2)
    ratios = plotting.signed_ratios(rep.ratios, raw)
    columns = {k: ["TCP"] if r.shape[1] == 1 else list(robot.joint_names) for k, r in ratios.items()}
    mx = np.maximum.reduce([r.max(axis=1) for k, r in rep.ratios.items() if k != "position"])
    axes[2].fill_between(plan.t, -1.1, 1.1, where=mx < 0.98, color="0.9", label="no limit active", step="mid")
    plotting.limit_panel(axes[2], plan.t, ratios, columns)
    axes[2].set_xlabel("t [s]")
    for ax in axes[:2]:
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    return plotting.save_figure(fig, path, dpi=120)


def _print_active(plan: CpPlan) -> None:
    out = console.out
    out.print("  binding limits (≥ 98 % of the bound):")
    for s in plan.active_segments:
        out.print(
            f"    {s.t_start_s:6.3f}–{s.t_end_s:6.3f} s   σ {s.sigma_start_m:6.3f}–{s.sigma_end_m:6.3f} m   "
            f"{s.limit} {s.joint}"
        )


# --- the stage --------------------------------------------------------------------------------------
Method = Literal["nlp", "toppra"]

# The options, named here so that `command` reads as a list.
PathOption = Annotated[
    Path | None, typer.Option("--path", help="Path file (kind rxcomm/Path), TCP in the base frame.")
]
CalibrationOption = Annotated[
    Path | None,
    typer.Option(
        help="calibration.yaml: IK along the path on the calibrated robot, its joint compliance "
        "compensated (the encoder angles that hold the links on it)."
    ),
]
EnergyWeightOption = Annotated[
    float, typer.Option(help="Weight of τᵀτ in ∫(k1 + k2·τᵀτ)dt, 1/(N·m)² (needs nlp).")
]
TorqueRateOption = Annotated[
    bool,
    typer.Option(
        "--torque-rate-limits/--no-torque-rate-limits", help="Honour the drives' torque-rate limits."
    ),
]
MethodOption = Annotated[
    Method, typer.Option(help="nlp: the path NLP warm-started by toppra; toppra: toppra alone (fast).")
]
IntervalsOption = Annotated[int, typer.Option("--path-intervals", help="Grid intervals along the path.")]
TcpSpeedOption = Annotated[
    float | None,
    typer.Option("--max-tcp-speed-m-s", help="TCP speed limit, m/s (default: the path file's, else none)."),
]
TcpAccelerationOption = Annotated[
    float | None,
    typer.Option(
        "--max-tcp-acceleration-m-s2",
        help="TCP acceleration limit, m/s² (default: the path file's, else none).",
    ),
]
PlotOption = Annotated[
    bool, typer.Option(help="Write NAME.png: TCP speed (Fig. 7), binding limits (Fig. 8).")
]
# The old spelling of `rxcomm iso9283-paths -o DIR [--cell C] [--tcp-rpy-deg R]` (hidden, deprecated).
Iso9283Option = Annotated[Path | None, typer.Option(hidden=True)]
CellOption = Annotated[Path | None, typer.Option(hidden=True)]
IsoRpyOption = Annotated[str, typer.Option(hidden=True)]
TimingOption = Annotated[
    Timing,
    typer.Option(
        help="optimal: the planner under the model's torque limits; catalogue: a generic controller's "
        "toppra timing from the catalogue joint speeds/accelerations of the prior model with the rated "
        "payload (no torque limits; --method, --k2, --torque-rate do not apply)."
    ),
]


@stage("plan-cp")
def command(
    robot_dir: RobotDir,
    path: PathOption = None,
    output: Annotated[Path | None, TRAJECTORY_OUTPUT] = None,
    dynamics: Path | None = None,
    payload: Path | None = None,
    calibration: CalibrationOption = None,
    k1: TimeWeight = 1.0,
    k2: EnergyWeightOption = 0.0,
    objective: Objective = "torque",
    duration_s: PlanDuration = None,
    torque_rate: TorqueRateOption = True,
    method: MethodOption = "nlp",
    intervals: IntervalsOption = 200,
    tcp_speed_max: TcpSpeedOption = None,
    tcp_acceleration_max: TcpAccelerationOption = None,
    plot: PlotOption = False,
    iso9283: Iso9283Option = None,
    cell: CellOption = None,
    iso_rpy_deg: IsoRpyOption = "180,0,0",
    timing: TimingOption = "optimal",
) -> dict[str, object]:
    """Plan the time-optimal (or time/energy-weighted) timing of a TCP path and write it for `run`."""
    from rxcomm.calibration.loading import load_calibrated_robot
    from rxcomm.model.catalogue import catalogue_limits
    from rxcomm.model.payload import model_inputs, model_name
    from rxcomm.model.robot import load_robot
    from rxcomm.planning.cp import CpSettings
    from rxcomm.planning.paths import load_path

    if iso9283 is not None:  # the old spelling of `rxcomm iso9283-paths`
        from rxcomm.stages import iso9283_paths

        console.err.print("plan-cp --iso9283 DIR is deprecated: use rxcomm iso9283-paths -o DIR")
        return iso9283_paths.command(robot_dir, iso9283, cell=cell, tcp_rpy_deg=iso_rpy_deg)
    t_all = time.perf_counter()
    path, output = _given_paths(path, output)
    files = {"path": path, "dynamics": dynamics, "payload": payload, "calibration": calibration}
    DECLARATIONS["plan-cp"].check(output=output, plot=plot, robot=robot_dir, **files)
    robot = load_robot(robot_dir)
    inputs = {"urdf": robot.urdf_path, "drives": robot.drives_path, "path": path}
    catalogue = catalogue_limits(robot) if timing == "catalogue" else None  # the maker's: prior, nominal
    method, torque_rate, k2 = ("toppra", False, 0.0) if catalogue else (method, torque_rate, k2)
    nominal = robot  # the torque model's robot: identify's and run's (`load_calibrated_robot` says why)
    if calibration is not None:
        robot = load_calibrated_robot(robot, calibration)
        inputs["calibration"] = Path(calibration)
    spec, cpath = load_path(path, robot)
    given = dict(k1=k1, k2=k2, torque_rate=torque_rate, method=method, intervals=intervals)
    given |= dict(objective=objective, duration_s=duration_s)
    given["tcp_speed_max_m_s"] = _given_or(tcp_speed_max, spec.limits.tcp_speed_max_m_s)
    given["tcp_acceleration_max_m_s2"] = _given_or(
        tcp_acceleration_max, spec.limits.tcp_acceleration_max_m_s2
    )
    names = {name: name.replace("_", "-") for name in CpSettings.model_fields}
    settings = settings_from_options(CpSettings, given, names)
    inputs |= model_inputs(dynamics, payload)
    dyn, command, compliance = _torque_model(
        nominal, calibration, dynamics, payload, settings.coulomb_eps_rad_s
    )
    label = f"plan-cp: {spec.name or path.name} ({timing if catalogue else settings.method}, N = {intervals})"
    plan = _timed_plan(robot, cpath, dyn, settings, catalogue, label, command)
    run_settings = {
        **settings.model_dump(mode="json"),
        "dynamics_model": model_name(dynamics, payload),
        "calibrated": calibration is not None,
        "compliance_compensated_rad_per_nm": compliance,
        "branch": plan.joint_path.labels,
        "timing": timing,
    }
    return _write(
        robot, plan, cpath, catalogue, inputs, run_settings, output, t_all, plot, spec.name or path.stem
    )


def _write(
    robot, plan, cpath, catalogue, inputs, settings, output: Path, t_all: float, plot: bool, name: str
):
    """The trajectory MCAP + YAML (and with `plot` the PNG); returns the summary."""
    from rxcomm.execution.plan_views import plan_views
    from rxcomm.io.trajectory import save_trajectory_mcap
    from rxcomm.planning.catalogue_timing import filtered_path_deviation_m

    summary = summary_of(plan, robot)
    summary |= planned_energy(robot, trajectory_of(plan), plan.nlp.bus_energy_j if plan.nlp else None)
    if catalogue is not None:  # how the limits were found; what the setpoint filter rounds off
        settings["catalogue"] = catalogue.as_dict()
        summary["catalogue_acceleration_bound"] = catalogue.binding_text()
        summary["max_filter_deviation_m"] = filtered_path_deviation_m(robot, plan, cpath)
    summary["seconds"] = time.perf_counter() - t_all
    env = TrajectorySummary.envelope(inputs, settings, summary)
    output.parent.mkdir(parents=True, exist_ok=True)
    save_trajectory_mcap(output, trajectory_of(plan), env, robot.joint_names, plan_views(robot))
    console.summary_table(f"plan-cp → {output}", summary)
    _print_active(plan)
    if plot:
        title = f"{name}: {plan.duration_s:.3f} s ({plan.method}, k2 = {settings['k2']:g}), "
        title += f"{plan.active_fraction:.1%} with a limit active"
        console.out.print(f"plot: {plot_cp(plan, robot, output.with_suffix('.png'), title)}")
    return summary


def _given_paths(path: Path | None, output: Path | None) -> tuple[Path, Path]:
    """The path and the output (NAME.mcap), both required."""
    if path is None:
        raise InputError("give the path to plan with --path PATH.yaml", field="path")
    if output is None:
        raise InputError("give the output with -o NAME.mcap", field="output")
    return Path(path), trajectory_output(output)


def _given_or(option: float | None, default: float | None) -> float | None:
    return option if option is not None else default


def _torque_model(
    nominal: Robot, calibration: Path | None, dynamics: Path | None, payload: Path | None, eps: float
):
    """The planner's torque model (identified or prior, with the payload if given) on the kinematics
    it was fitted on (the nominal robot's for the prior), and the compliance map and compliances the
    plan is commanded through (`_compliance`)."""
    from rxcomm.model.dynamics import prior_parameters
    from rxcomm.model.payload import model_parameters
    from rxcomm.planning.timing import PlanDynamics

    params, fitted = model_parameters(nominal, dynamics, payload)  # None: the prior
    dyn = PlanDynamics.from_parameters(fitted, params or prior_parameters(nominal), eps)
    return dyn, *_compliance(fitted, calibration, params if dynamics is not None else None)


def _compliance(fitted: Robot, calibration: Path | None, params: DynamicParameters | None):
    """With a calibration that found joint compliance: the map link → encoder angles the plan
    commands (the torque model on its own kinematics `fitted`: the identified `params`, with the
    payload's weight when one is given) and the compliances; else (None, None)."""
    from rxcomm.calibration.compensation import compliance_command
    from rxcomm.schemas.calibration import Calibration

    if calibration is None:
        return None, None
    return compliance_command(fitted, read_yaml_artefact(calibration, Calibration), params)


def _timed_plan(robot, cpath, dyn, settings, catalogue, label: str, command=None) -> CpPlan:
    """The optimal plan, or with catalogue limits the generic controller's (`--timing catalogue`),
    commanded through `command` (the joint compliance) when given."""
    from rxcomm.planning.catalogue_timing import plan_cp_catalogue
    from rxcomm.planning.cp import plan_cp

    with console.phase(label) as status:

        def say(m: str) -> None:
            status.update(f"plan-cp: {m}")

        if catalogue is None:
            return plan_cp(robot, cpath, dyn, settings, progress=say, command=command)
        return plan_cp_catalogue(robot, cpath, catalogue, dyn, settings, progress=say, command=command)
