"""A trajectory run: checks, the approach move, the plan streamed into the run log writer.

``run_trajectory`` is the run on a connected gateway (``Session`` does the streaming);
``execute_trajectory`` is what `rxcomm run` does with a trajectory plan once the gateway is connected:
the run with the log written while the robot moves, the tracker channel added (a caller's hook: the
embedded cell's samples, aligned by ``rxcomm.acceptance``), the log kept as ``.part`` if anything
fails outside the run.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rxcomm.errors import GatewayError, LocatedError, RxcommError, SafetyStop
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.handover import hand_over
from rxcomm.execution.log import RunLogWriter
from rxcomm.execution.plan import StreamPlan, distance_to_start, prepare_plan
from rxcomm.execution.records import RecordSink, RunResult
from rxcomm.execution.session import (
    RunSettings,
    Session,
    StreamStopped,
    interrupt_reason,
    log_write_error,
)
from rxcomm.gateway.client import GatewayClient
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot


def execute_trajectory(
    client: GatewayClient,
    robot: Robot,
    plan: StreamPlan,
    params: DynamicParameters,
    settings: RunSettings,
    writer: RunLogWriter,
    progress: Callable[[str, float], None] | None = None,
    tracker: Callable[[RunResult, RunLogWriter], None] | None = None,
) -> RunResult:
    """``run_trajectory`` into ``writer`` (the log is on disk as ``NAME.mcap.part`` while the robot
    moves), then ``tracker(result, writer)`` (adds ``/run/tracker``). The caller closes the writer
    with the result (``writer.close``) once the cell is released; on any exception here the log is
    kept as ``.part`` (``writer.abandon``) and the exception goes on."""
    try:
        result = run_trajectory(client, robot, plan, params, settings, progress, writer)
        if tracker is not None:
            tracker(result, writer)
    except BaseException:
        writer.abandon()
        raise
    return result


def run_trajectory(
    client: GatewayClient,
    robot: Robot,
    plan: StreamPlan,
    params: DynamicParameters,
    settings: RunSettings | None = None,
    progress: Callable[[str, float], None] | None = None,
    sink: RecordSink | None = None,
) -> RunResult:
    """Execute a prepared ``plan`` (``prepare_plan``) on a connected gateway. ``params`` is the model
    for the approach move's feed-forward and limit check. Refusals before motion raise (InputError,
    GatewayError, SafetyStop); a stop during motion is returned in ``RunResult.error`` with the log
    recorded up to it. ``progress(what, fraction)`` is called at ≤ 10 Hz while streaming; ``sink`` (the
    run log writer) gets the plan's records while it streams."""
    settings = settings or RunSettings()
    ses = Session(client, robot, settings.stream)
    ses.check_identity()
    ses.check_faults(settings.fault_reset)
    q_now = ses.positions()
    dist = distance_to_start(robot, q_now, plan.q[0])
    approach: StreamPlan | None = None
    if max(dist.values()) > settings.start_tolerance_rad:
        if not settings.approach:
            far = ", ".join(f"{k} {v:.4f}" for k, v in dist.items())
            raise SafetyStop(
                f"the robot is not at the plan's start (distance per joint, rad: {far}; tolerance "
                f"{settings.start_tolerance_rad:g}); use --approach to move there first"
            )
        move = move_trajectory(
            robot, q_now, plan.q[0], ses.cycle_s, settings.approach_speed_fraction, paced_by=params
        )
        approach = prepare_plan(
            robot,
            move,
            params,
            ses.cycle_s,
            feedforward=settings.feedforward,
            limit_tolerance=settings.limit_tolerance,
            what="approach move",
        )
    ses.configure()
    result = RunResult(
        gateway=ses.address, ratio=ses.ratio, cycle_s=ses.cycle_s, round_trip_probe_s=ses.probe_s
    )
    stage = "approach"
    try:
        client.enable_all()
        held = ses.demand()
        start = approach.q[0] if approach is not None else plan.q[0]
        if np.max(np.abs(held - start)) > settings.start_tolerance_rad:
            raise SafetyStop(f"the robot moved while enabling: {np.round(held - start, 5).tolist()} rad")
        if settings.handover:  # the arm's weight to the drives' integrators first
            hand_over(ses, robot, params, held)
        if approach is not None:
            result.approach = ses.stream(approach, _named(progress, "approach"))
        stage = "plan"
        result.log = ses.stream(plan, _named(progress, "run"), sink)
        result.stop_note = ses.stop_drives(after_stop=False)
    except StreamStopped as s:
        if stage == "approach":
            result.approach = s.log
        else:
            result.log = s.log
        result.error = _during(s.error, stage, approach is not None)
        result.stop_note = ses.stop_drives(after_stop=True)
    except (GatewayError, SafetyStop) as e:  # enable failed or refused after enabling
        result.error = _during(e, stage, approach is not None)
        result.stop_note = ses.stop_drives(after_stop=True)
    except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM where the stage turns it into Terminated
        result.error = _during(SafetyStop(interrupt_reason(e)), stage, approach is not None)
        result.stop_note = ses.stop_drives(after_stop=True)
    except OSError as e:  # the run log could not be opened (a full disk) with the drives enabled
        result.error = log_write_error(e, sink)
        result.stop_note = ses.stop_drives(after_stop=True)
    return result


def _during(error: RxcommError, stage: str, moved: bool) -> RxcommError:
    """A stop before the plan's first setpoint says so: "during the approach move" (the robot was on
    its way to the plan's start), or "before the plan started" (enabling)."""
    if stage != "approach":
        return error
    where = "during the approach move to the plan's start" if moved else "before the plan started"
    if isinstance(error, LocatedError):
        return type(error)(f"{where}: {error.reason}", file=error.file, field=error.field)
    if isinstance(error, GatewayError | SafetyStop):
        return type(error)(f"{where}: {error}")
    return error


def _named(progress: Callable[[str, float], None] | None, what: str) -> Callable[[float], None] | None:
    if progress is None:
        return None
    return lambda f: progress(what, f)
