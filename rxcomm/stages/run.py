"""`rxcomm run`: execute a plan on the robot cell over the drive gateway (paper §2.3, architecture §7 run).

PLAN is a trajectory MCAP (excite / plan-cp / plan-ptp) or a pose list (`configs.yaml` from
select-configs: a measurement campaign). Trajectory → ``-o NAME.mcap`` (+ ``NAME.yaml``, kind
`rxcomm/RunLog`); pose list → ``-o NAME.yaml`` (kind `rxcomm/Measurements`, what `calibrate` reads).
Without ``--gateway`` an embedded simulated cell is started on an ephemeral loopback port.
``--calibration`` makes a trajectory run log's 3D view the calibrated robot's, with the tracker
frame (nothing else).

Long because one stage runs both kinds of plan and its CLI options are declared here.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from rxcomm import console, plotting
from rxcomm.errors import DriveTrip, GatewayError, InputError, LocatedError, RxcommError, SafetyStop
from rxcomm.io.plan_files import plan_kind
from rxcomm.io.validate import check_kind
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.options import Plant, RobotDir, embedded_plant
from rxcomm.schemas.configs import Configs
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages.declarations import DECLARATIONS
from rxcomm.stages.stage_cli import stage

if TYPE_CHECKING:
    from rxcomm.execution.campaign import CampaignSettings
    from rxcomm.execution.log import RunLogWriter
    from rxcomm.execution.records import RunResult
    from rxcomm.execution.session import RunSettings
    from rxcomm.gateway.client import GatewayClient
    from rxcomm.model.dynamics import DynamicParameters
    from rxcomm.model.robot import Robot


# --- inputs ---------------------------------------------------------------------------------------
def load_model(
    robot: Robot, dynamics: Path | None, plan: Path | None = None, payload: Path | None = None
) -> tuple[DynamicParameters, str, Robot]:
    """The model for τ_ff and the torque checks; `payload` (payload.yaml) added to its last link; and
    the robot it is evaluated on: the nominal `robot` with the kinematics the model was fitted on."""
    from rxcomm.model.base_parameters import load_dynamics
    from rxcomm.model.dynamics import prior_parameters
    from rxcomm.model.payload import load_payload, with_payload

    if dynamics is not None:
        (params, robot), name = load_dynamics(dynamics, robot), "identified"
        from rxcomm.execution.guards import other_model_warning

        if plan is not None and (warning := other_model_warning(plan, dynamics)):
            console.err.print(f"warning: {warning}")
    else:
        params, name = prior_parameters(robot), "prior"
    if payload is None:
        return params, name, robot
    return with_payload(robot, params, load_payload(payload, robot)), name, robot  # the log's inputs name it


def _model_and_cell_files(
    gateway: str | None,
    truth: Path | None,
    robot_dir: Path,
    truth_payload: Path | None,
    dynamics: Path | None,
    payload: Path | None,
) -> dict[str, Path | None]:
    """The files run reads besides the plan: the model (--dynamics, --payload) and the embedded cell's
    truth (and --truth-payload, which only an embedded cell can carry)."""
    if gateway is not None and truth_payload is not None:
        raise InputError(
            "--truth-payload loads the embedded simulated cell, not a --gateway", field="truth-payload"
        )
    truth = None if gateway is not None else (truth or Path(robot_dir) / "truth.yaml")
    return {"dynamics": dynamics, "payload": payload, "truth": truth, "truth-payload": truth_payload}


def load_poses(path: Path) -> Configs:
    return read_yaml_artefact(path, Configs)


def check_joint_names(cfg: Configs, path: Path, robot: Robot) -> Configs:
    if list(cfg.joint_names) != list(robot.joint_names):
        raise InputError(
            f"poses are for joints {cfg.joint_names}, the robot has {list(robot.joint_names)}",
            file=path,
            field="joint_names",
        )
    return cfg


# --- the cell -------------------------------------------------------------------------------------
@contextlib.contextmanager
def connect(
    gateway: str | None,
    allow_remote: bool,
    truth: Path | None,
    robot_dir: Path,
    realtime: bool,
    plant: str,
    truth_payload: Path | None = None,
) -> Iterator[tuple[GatewayClient, Any]]:
    """A connected client and the embedded cell's server (None: a gateway); stops an embedded cell on exit."""
    from rxcomm.execution.session import REQUEST_TIMEOUT_S, VIRTUAL_CELL_REQUEST_TIMEOUT_S
    from rxcomm.gateway.client import GatewayClient
    from rxcomm.gateway.net import parse_gateway_address

    server = None
    if gateway is None:
        try:
            from rxcomm.cell.sim import start_embedded_cell  # the simulator, only when asked for
        except ModuleNotFoundError as e:
            raise GatewayError("this build has no simulated cell (rxcomm.cell.sim): pass --gateway") from e

        truth = Path(truth) if truth is not None else Path(robot_dir) / "truth.yaml"
        if not truth.is_file():
            raise InputError(
                "no truth file for the embedded simulated cell (pass --truth or --gateway)", file=truth
            )
        server = start_embedded_cell(
            truth, port=0, realtime=realtime, plant=plant, payload_path=truth_payload
        )
        host, port = server.host, server.port
        pacing = "realtime" if realtime else "virtual time"
        notes = "".join(f"\n  not faithful: {n}" for n in server.core.backend.plant_notes)
        load = "" if truth_payload is None else f", payload {truth_payload}"
        console.err.print(
            f"embedded simulated cell on {host}:{port} ({pacing}, {truth}{load}, {plant}){notes}"
        )
    else:
        host, port = parse_gateway_address(gateway, allow_remote)
    try:
        virtual = server is not None and not realtime
        timeout_s = VIRTUAL_CELL_REQUEST_TIMEOUT_S if virtual else REQUEST_TIMEOUT_S
        client = GatewayClient(host, port, timeout_s=timeout_s, allow_remote=allow_remote)
        client.connect()
        try:
            yield client, server
        finally:
            client.close()
    finally:
        if server is not None:
            server.stop()


def _with_context(error: RxcommError, note: str, written: Path | None) -> RxcommError:
    """The stop, one line, with what became of the drives and where the log is."""
    extra = "; ".join(p for p in (note, f"log kept in {written}" if written else "") if p)
    text = f"{error}; {extra}" if extra else str(error)
    if isinstance(error, GatewayError):
        return GatewayError(text)
    if isinstance(error, SafetyStop):
        return SafetyStop(text)
    if isinstance(error, LocatedError) and extra:
        return type(error)(f"{error.reason}; {extra}", file=error.file, field=error.field)
    return error


def record_tracker(server: Any, robot: Robot, result: RunResult, sink: RunLogWriter) -> None:
    """The embedded cell's tracker samples of this run, aligned, as the log's /run/tracker channel.

    Aligned on the writer's ``encoder_prefix`` (the first ``CORRELATE_S`` of encoder angles, all the
    cross-correlation looks at): the master does not keep a run's records (architecture §7 run)."""
    from rxcomm.acceptance.alignment import CORRELATE_S, tracker_channel

    export = server.tracker_export()
    log = result.log
    if export is None or export.n < 2 or log is None or log.n_records < 2 or not sink.begun:
        return
    sample_s = result.ratio * result.cycle_s
    try:
        channel = tracker_channel(robot, export, sink.encoder_prefix, sample_s, correlate_s=CORRELATE_S)
    except InputError as e:  # no alignment: the run stands, without a tracker channel
        console.err.print(f"warning: tracker samples not recorded: {e}")
        return
    sink.tracker(export.t_s, export.position_m, export.quaternion_wxyz, channel)


# --- the stage ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Job:
    """What both kinds of plan share once the inputs are read."""

    plan: Path
    output: Path
    robot: Robot  # the kinematics the torque model was fitted on (`load_model`): same drives and limits
    params: DynamicParameters
    model_name: str
    inputs: dict[str, Path]
    connect: Callable[[], contextlib.AbstractContextManager[tuple[GatewayClient, Any]]]
    progress: Callable[[str, float], None] | None
    view: Any = None  # --calibration's CalibratedView, or None


def _inputs(
    plan: Path, robot: Robot, dynamics: Path | None, calibration: Path | None, payload: Path | None = None
) -> tuple[dict[str, Path], Any]:
    """The envelope's inputs, and --calibration's view (``CalibratedView``: the calibrated robot and
    URDF and the tracker frame in the log's 3D view, nothing else) or None."""
    inputs: dict[str, Path] = {"plan": plan, "urdf": robot.urdf_path, "drives": robot.drives_path}
    if dynamics is not None:
        inputs["dynamics"] = Path(dynamics)
    if payload is not None:
        inputs["payload"] = Path(payload)
    if calibration is None:
        return inputs, None
    from rxcomm.calibration.loading import load_calibrated_robot, load_calibration
    from rxcomm.calibration.urdf import calibrated_urdf_text
    from rxcomm.execution.frames import CalibratedView

    calibrated = load_calibrated_robot(robot, calibration)  # exit 2 unless it is this robot's
    errors, tracker_to_base = load_calibration(calibration)
    inputs["calibration"] = Path(calibration)
    return inputs, CalibratedView(calibrated, calibrated_urdf_text(robot, errors), tracker_to_base)


def execute(
    plan: _Plan,
    robot_dir: RobotDir,
    output: _Output,
    *,
    gateway: _Gateway = None,
    truth: _Truth = None,
    dynamics: Path | None = None,  # τ_ff and the torque checks
    feedforward: _Feedforward = True,
    approach: _Approach = False,
    allow_remote: _AllowRemote = False,
    realtime: _Realtime = False,
    interpolation_ratio: _InterpolationRatio = None,
    speed: _Speed = 0.2,
    fault_reset: _FaultReset = False,
    trip_is_result: _TripIsResult = False,
    plot: _Plot = False,
    compare: _Compare = None,
    calibration: _Calibration = None,
    plant: Plant = "own",
    truth_payload: _TruthPayload = None,
    payload: Path | None = None,
    show_progress: bool = True,
) -> dict[str, Any]:
    """`command` as a function (tests call it): returns the summary written. Raises RxcommError."""
    from rxcomm.execution.campaign import CampaignSettings
    from rxcomm.execution.guards import check_run_options, sigterm_as_interrupt
    from rxcomm.execution.session import VIRTUAL_CELL_WATCHDOG_MS, RunSettings, StreamSettings
    from rxcomm.model.robot import load_robot

    plan, output = Path(plan), Path(output)
    plant = embedded_plant(plant, gateway)
    check_run_options(interpolation_ratio, speed)  # exit 2 before anything is read
    cfg = _read_plan(plan, output, trip_is_result)
    if compare is not None and not plot:
        raise InputError("--compare draws into the --plot figure: pass --plot too", field="compare")
    DECLARATIONS["run"].check(
        output=output,
        plot=plot,
        robot=robot_dir,
        plan=plan,
        **_model_and_cell_files(gateway, truth, robot_dir, truth_payload, dynamics, payload),
        compare=compare,
        calibration=calibration,
    )
    robot = load_robot(robot_dir)
    params, model_name, fitted = load_model(robot, dynamics, plan, payload)
    inputs, view = _inputs(plan, robot, dynamics, calibration, payload)
    virtual = gateway is None and not realtime  # the embedded cell's clock waits for the master
    lease = {"watchdog_ms": VIRTUAL_CELL_WATCHDOG_MS} if virtual else {}
    stream = StreamSettings(interpolation_ratio=interpolation_ratio, **lease)
    update, stop_bar = console.named_progress() if show_progress else (None, lambda: None)
    restore_sigterm = sigterm_as_interrupt()
    job = _Job(
        plan, output, fitted, params, model_name, inputs,
        lambda: connect(gateway, allow_remote, truth, robot_dir, realtime, plant, truth_payload), update,
        view,
    )  # fmt: skip
    try:
        if cfg is None:
            settings = RunSettings(
                feedforward=feedforward,
                approach=approach,
                handover=gateway is None and not feedforward,  # run's own cell: just powered on
                approach_speed_fraction=speed,
                fault_reset=fault_reset,
                trip_is_result=trip_is_result,
                stream=stream,
            )
            return _trajectory(job, settings, realtime, stop_bar, compare if plot else None, plot)
        settings_c = CampaignSettings(
            feedforward=feedforward, handover=gateway is None and not feedforward, speed_fraction=speed,
            fault_reset=fault_reset, stream=stream,
        )  # fmt: skip
        return _campaign(job, cfg, settings_c, stop_bar)
    finally:
        restore_sigterm()
        stop_bar()


def _read_plan(plan: Path, output: Path, trip_is_result: bool) -> Configs | None:
    """The pose list (None: a trajectory, its envelope checked), after the options that depend on
    the plan's kind; what the plan is comes first: a wrong-kind plan gets a message about the plan,
    not the output."""
    from rxcomm.execution.guards import check_output_kind
    from rxcomm.io.mcap_io import read_mcap_envelope

    kind = plan_kind(plan)
    if trip_is_result and kind == "poses":
        raise InputError("--trip-is-result is for a trajectory plan, not a pose list", field="trip-is-result")
    cfg = load_poses(plan) if kind == "poses" else None
    if kind == "trajectory" and plan.suffix.lower() == ".mcap":
        check_kind(read_mcap_envelope(plan), TrajectorySummary, file=plan, prefix="envelope")
    check_output_kind(kind, output)
    return cfg


def _trajectory(
    job: _Job,
    settings: RunSettings,
    realtime: bool,
    stop_bar: Callable[[], None],
    compare: Path | None,
    plot: bool,
) -> dict[str, Any]:
    """A trajectory plan: prepared and limit-checked, run with the log written while the robot moves
    (a killed run leaves NAME.mcap.part), the log finished, printed and plotted."""
    from rxcomm.acceptance.alignment import CORRELATE_S
    from rxcomm.execution.guards import deferred_termination
    from rxcomm.execution.log import RunLogWriter
    from rxcomm.execution.plan import prepare_plan
    from rxcomm.execution.trajectory_run import execute_trajectory
    from rxcomm.io.plan_files import load_plan_file

    robot, params = job.robot, job.params
    plan = load_plan_file(job.plan, robot.joint_names)
    cycle_s = robot.drives.cycle_s
    prepared = prepare_plan(
        robot,
        plan.trajectory,
        params,
        cycle_s,
        feedforward=settings.feedforward,
        limit_tolerance=settings.limit_tolerance,
        what=f"plan {job.plan.name}",
        sample_label=plan.label,
    )
    for joint, ratio in prepared.smooth_sign_joints if settings.feedforward else ():
        console.err.print(
            f"note: {joint}'s feed-forward keeps the smooth Coulomb sign: held through its stops it would "
            f"reach {ratio:.3f} × its torque-rate limit (architecture §6.1)"
        )
    with deferred_termination(), job.connect() as (client, server):
        embedded = server is not None
        sink = RunLogWriter(
            job.output,
            robot,
            inputs=job.inputs,
            settings={
                **settings.model_dump(mode="json"),
                "model": job.model_name,
                "embedded_cell": embedded,
                "plant": getattr(server.core.backend, "plant_name", None) if embedded else None,
                "realtime": realtime,
            },
            feedforward=job.model_name if settings.feedforward else "none",
            embedded_cell=embedded,
            keep_encoder_s=CORRELATE_S if embedded else 0.0,
            view=job.view,
        )
        tracker = functools.partial(record_tracker, server, robot) if embedded else None
        result = execute_trajectory(client, robot, prepared, params, settings, sink, job.progress, tracker)
    stop_bar()
    # a drive trip on the plan's own motion (not the approach, not Ctrl-C or the link) is its result
    tripped = settings.trip_is_result and isinstance(result.error, DriveTrip) and result.log is not None
    try:
        written, summary = sink.close(result, stop_is_result=tripped)
    except OSError as e:  # a full disk: the stop is controlled, the log is what reached the disk
        raise _with_context(
            result.error or console.os_error(e),
            result.stop_note,
            sink.part_path if sink.part_path.exists() else None,
        ) from e
    _print_run(summary, written, robot)
    if plot:
        figure = plot_lags(written, compare, job.output.with_suffix(".png"), robot)
        console.out.print(f"figure: {figure}")
    if tripped:
        console.err.print(
            f"warning: {_with_context(result.error, result.stop_note, None)}; the run's result "
            f"(--trip-is-result): {written}"
        )
    elif result.error is not None:
        raise _with_context(result.error, result.stop_note, written)
    return summary


def _campaign(
    job: _Job, cfg: Configs, settings: CampaignSettings, stop_bar: Callable[[], None]
) -> dict[str, Any]:
    """A pose list: checked before touching the cell, measured pose by pose (each on disk as it is
    taken), the measurements written."""
    from rxcomm.execution.campaign import CampaignLog, check_poses, execute_campaign
    from rxcomm.execution.guards import deferred_termination

    robot = job.robot
    check_joint_names(cfg, job.plan, robot)
    check_poses(robot, [p.q_rad for p in cfg.poses])  # refused before touching the cell
    with deferred_termination(), job.connect() as (client, server):
        env_settings = {
            **settings.model_dump(mode="json"),
            "model": job.model_name,
            "embedded_cell": server is not None,
            "plant": getattr(server.core.backend, "plant_name", None) if server is not None else None,
        }
        log = CampaignLog(job.output, robot, [p.role for p in cfg.poses], job.inputs, env_settings)
        poses = [p.q_rad for p in cfg.poses]
        camp = execute_campaign(client, robot, poses, job.params, settings, log, job.progress)
    stop_bar()
    try:
        written, summary = log.write(camp)
    except OSError as e:  # a full disk: the poses so far are in the .part written with the last one
        raise _with_context(
            camp.run.error or console.os_error(e), camp.run.stop_note, log.part if log.part.exists() else None
        ) from e
    console.summary_table(
        f"run: {summary['n_valid']}/{summary['n_poses']} poses measured → {written}", summary
    )
    if camp.run.error is not None:
        raise _with_context(camp.run.error, camp.run.stop_note, written)
    return summary


def _print_run(summary: dict[str, Any], written: Path, robot: Robot) -> None:
    keys = (
        "outcome", "duration_s", "underruns", "cell_overruns", "max_lag_rad", "rms_lag_rad",
        "max_tcp_error_m", "interpolation_ratio", "n_records", "lost_records", "min_lead_s",
        "round_trip_p50_s", "round_trip_p99_s", "approach_s",
    )  # fmt: skip
    console.summary_table(f"run → {written}", {k: summary[k] for k in keys if k in summary})


def plot_lags(log_path: Path, compare: Path | None, out: Path, robot: Robot) -> Path:
    """PNG: lag (following) error per joint over time, and the TCP error; with ``compare``, both runs
    (the paper's Fig. 2: with and without feed-forward)."""
    from rxcomm.io.run_log import read_run_log
    from rxcomm.schemas.run_settings import RunLogSettings

    plt = plotting.pyplot()

    logs = [read_run_log(log_path)]
    if compare is not None:
        logs.append(read_run_log(compare))
    n = robot.n
    fig, axes = plt.subplots((n + 2) // 2, 2, sharex=True, figsize=(10, 2.0 * ((n + 2) // 2)))
    axes = axes.ravel()
    for k, (log, path) in enumerate(zip(logs, [log_path, compare], strict=False)):
        settings = RunLogSettings.model_validate(log.envelope.get("settings", {}))
        on = settings.feedforward
        ff = "feed-forward not recorded" if on is None else "feed-forward off"
        ff = f"feed-forward ({settings.model or 'model not recorded'})" if on else ff
        label = f"{Path(path).name}: {ff}"
        j = log.joints
        style = {"lw": 0.9, "alpha": 0.9 if k == 0 else 0.7}
        for i in range(n):
            axes[i].plot(j.t, 1e3 * j["following_error"][:, i], label=label, **style)
        axes[n].plot(j.t, 1e3 * j["tcp_error_m"], label=label, **style)
    for i in range(n):
        axes[i].set_ylabel(f"{robot.joint_names[i]} lag [mrad]")
        axes[i].grid(alpha=0.3)
    axes[n].set_ylabel("TCP error [mm]")
    axes[n].grid(alpha=0.3)
    for ax in axes[n + 1 :]:
        ax.axis("off")
    plotting.legend_outside(axes[n])  # beside the TCP panel, over no data
    for ax in axes[max(0, n - 1) : n + 1]:
        ax.set_xlabel("t [s]")
    fig.suptitle("lag errors per joint and TCP error (nominal kinematics)")
    return plotting.save_figure(fig, out, dpi=110)


# execute's parameters, the options as typer reads them (`command` takes them from execute)
_Plan = Annotated[
    Path,
    typer.Argument(
        help="A trajectory NAME.mcap (excite, plan-cp, plan-ptp) or a pose list configs.yaml "
        "(select-configs: a measurement campaign)."
    ),
]
_Output = Annotated[
    Path,
    typer.Option(
        "-o",
        "--output",
        help="Trajectory: the run log NAME.mcap (/run/joints at the setpoint rate, /run/gateway) with "
        "its summary NAME.yaml beside it. Pose list: the measurements NAME.yaml (e.g. calib-meas.yaml) "
        "that calibrate reads. A run that ends in a stop keeps its output as NAME.part.",
    ),
]
_Gateway = Annotated[
    str | None,
    typer.Option(
        help="Drive gateway HOST:PORT. Default: an embedded simulated cell on an ephemeral loopback port."
    ),
]
_Truth = Annotated[
    Path | None, typer.Option(help="The embedded cell's truth file (default: ROBOT_DIR/truth.yaml).")
]
_TruthPayload = Annotated[
    Path | None,
    typer.Option(
        help="Embedded cell: the payload it carries for this run (rxcomm/CellPayload YAML; replaces the "
        "truth's payload, `payload: null` none)."
    ),
]
_Feedforward = Annotated[
    bool, typer.Option("--feedforward/--no-feedforward", help="Stream τ_ff = M(q)q̈ + g(q, q̇), or zeros.")
]
_Approach = Annotated[
    bool, typer.Option(help="If the robot is not at the plan's start, move there first (jerk-limited).")
]
_AllowRemote = Annotated[bool, typer.Option(help="Allow a non-loopback --gateway (a real cell).")]
_Realtime = Annotated[bool, typer.Option(help="Embedded cell: wall-clock pacing (demos).")]
_InterpolationRatio = Annotated[
    int | None,
    typer.Option(help="Drive cycles per setpoint (1-64). Default: chosen from the measured round trip."),
]
_Speed = Annotated[
    float,
    typer.Option(
        "--speed-fraction",
        help="Approach and campaign moves: fraction of the velocity/acceleration limits.",
    ),
]
_FaultReset = Annotated[
    bool, typer.Option(help="Reset drive faults and latched gateway stops before moving.")
]
_TripIsResult = Annotated[
    bool,
    typer.Option(
        help="A drive trip on the plan's motion (0x8611 following error, a torque fault) is the run's "
        "result, as for the plan without feed-forward (paper Fig. 2): NAME.mcap and NAME.yaml are "
        "written with the stop in the summary, exit 0. Other stops still keep NAME.part (exit 4/5)."
    ),
]
_Plot = Annotated[bool, typer.Option(help="Write NAME.png: lag errors per joint and TCP error over time.")]
_Calibration = Annotated[
    Path | None,
    typer.Option(
        help="calibration.yaml: the run log's 3D view on the calibrated robot, with the tracker frame."
    ),
]
_Compare = Annotated[
    Path | None,
    typer.Option(help="Another run log to draw in the --plot figure (e.g. the run without feed-forward)."),
]


@stage("run", signature_of=execute)
def command(**options: Any) -> None:
    """Execute a trajectory (or a pose list) on the cell: stream setpoints + feed-forward torque (from
    --dynamics, else the prior model; also the torque checks), record,
    report lag errors. Exit 2 bad input, 4 communication fault, 5 safety stop or a plan outside the
    limits / not at its start."""
    execute(**options)
