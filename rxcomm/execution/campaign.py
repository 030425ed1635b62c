"""A measurement campaign: drive to each pose of a pose list, settle, read the tracker (paper §3.4).

Every move (current position → pose 1 → pose 2 → …) is planned and limit-checked before the drives
are enabled. Per pose: stream the jerk-limited move and ``settle_s`` of holding the goal (a streamed
hold settles the drives in virtual time too), read the tracker — it answers only at standstill — up
to ``tracker_attempts`` times, then the encoders. A pose
whose tracker never answers is recorded with ``valid=False`` (NaN position), not an error.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import Field

from rxcomm.errors import GatewayError, InputError, RxcommError, SafetyStop
from rxcomm.execution.approach import move_trajectory
from rxcomm.execution.guards import raise_if_terminated
from rxcomm.execution.handover import hand_over
from rxcomm.execution.plan import StreamPlan, prepare_plan
from rxcomm.execution.records import RunResult, timing_figures
from rxcomm.execution.session import Session, StreamSettings, StreamStopped, interrupt_reason
from rxcomm.gateway.client import GatewayClient, TrackerSample
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE
from rxcomm.model.robot import Robot
from rxcomm.schemas.measurements import MeasuredPose, Measurements
from rxcomm.schemas.strict import Strict


class CampaignSettings(Strict):
    feedforward: bool = True
    handover: bool = Field(
        False, description="without feed-forward, the static torque to the drives first (RunSettings)"
    )
    speed_fraction: float = Field(0.2, gt=0, le=1, description="of velocity and acceleration limits")
    settle_s: float = Field(0.5, ge=0, description="demand held at each pose before reading the tracker, s")
    tracker_attempts: int = Field(20, ge=1, description="tracker reads per pose before giving up")
    tracker_retry_s: float = Field(0.05, ge=0, description="pause between tracker reads, s")
    limit_tolerance: float = Field(SAMPLED_LIMIT_TOLERANCE, ge=0)
    fault_reset: bool = False
    stream: StreamSettings = StreamSettings()


@dataclass(frozen=True)
class PoseReading:
    """One pose as measured: encoders after settling and the tracker sample (None: never valid)."""

    index: int
    q_commanded: np.ndarray
    q_rad: np.ndarray
    tracker: TrackerSample | None
    attempts: int


@dataclass
class CampaignResult:
    run: RunResult
    n_planned: int
    readings: list[PoseReading] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def n_valid(self) -> int:
        return sum(r.tracker is not None for r in self.readings)


def check_poses(robot: Robot, poses: Sequence[Sequence[float]], tolerance: float = 0.0) -> np.ndarray:
    """Poses as an [n, dof] array; InputError for a malformed list, SafetyStop naming the pose and
    joint for one outside the joint limits."""
    if len(poses) == 0:
        raise InputError("the pose list is empty", field="poses")
    for i, p in enumerate(poses):
        if len(p) != robot.n or not np.all(np.isfinite(np.asarray(p, dtype=float))):
            raise InputError(
                f"expected {robot.n} finite joint angles, got {list(p)}", field=f"poses[{i}].q_rad"
            )
    q = np.asarray(poses, dtype=float)
    half = (robot.q_max - robot.q_min) / 2
    ratio = np.abs(q - (robot.q_max + robot.q_min) / 2) / half
    if ratio.max() > 1.0 + tolerance:
        i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        raise SafetyStop(
            f"pose {i} is outside the joint limits: {robot.joint_names[j]} = {q[i, j]:.4f} rad, "
            f"limits [{robot.q_min[j]:.4f}, {robot.q_max[j]:.4f}]"
        )
    return q


def plan_moves(
    robot: Robot,
    q_start: np.ndarray,
    poses: np.ndarray,
    params: DynamicParameters,
    cycle_s: float,
    settings: CampaignSettings,
) -> list[StreamPlan]:
    """The chain of moves start → pose 0 → pose 1 → …, each resampled, with τ_ff, limit-checked."""
    plans = []
    q_from = np.asarray(q_start, dtype=float)
    for i, q_to in enumerate(poses):
        move = move_trajectory(
            robot, q_from, q_to, cycle_s, settings.speed_fraction, settings.settle_s, paced_by=params
        )
        plans.append(
            prepare_plan(
                robot,
                move,
                params,
                cycle_s,
                feedforward=settings.feedforward,
                limit_tolerance=settings.limit_tolerance,
                what=f"move to pose {i}",
            )
        )
        q_from = q_to
    return plans


def run_campaign(
    client: GatewayClient,
    robot: Robot,
    poses: Sequence[Sequence[float]],
    params: DynamicParameters,
    settings: CampaignSettings | None = None,
    progress: Callable[[str, float], None] | None = None,
    on_pose: Callable[[CampaignResult], None] | None = None,
) -> CampaignResult:
    """Drive to every pose and read the tracker there. Refusals before motion raise; a stop during
    the campaign is returned in ``result.run.error`` with the readings taken so far. ``on_pose`` gets
    the result after every pose measured (the stage writes the measurements so far: a killed
    campaign keeps them)."""
    settings = settings or CampaignSettings()
    t_start = time.perf_counter()
    q_poses = check_poses(robot, poses, settings.limit_tolerance)
    ses = Session(client, robot, settings.stream)
    ses.check_identity()
    ses.check_faults(settings.fault_reset)
    q_now = ses.positions()
    moves = plan_moves(robot, q_now, q_poses, params, ses.cycle_s, settings)
    ses.configure()
    run = RunResult(gateway=ses.address, ratio=ses.ratio, cycle_s=ses.cycle_s, round_trip_probe_s=ses.probe_s)
    result = CampaignResult(run, n_planned=len(moves))
    try:
        client.enable_all()
        held = ses.demand()
        if np.max(np.abs(held - q_now)) > 1e-3:
            raise SafetyStop(f"the robot moved while enabling: {np.round(held - q_now, 5).tolist()} rad")
        if settings.handover:  # the arm's weight to the drives' integrators first
            hand_over(ses, robot, params, held)
        for i, move in enumerate(moves):
            if progress is not None:
                progress("poses", i / len(moves))
            run.moves.append(ses.stream(move))
            sample, attempts = _settle_and_read(ses, settings)
            result.readings.append(PoseReading(i, q_poses[i], ses.positions(), sample, attempts))
            if on_pose is not None:
                on_pose(result)
        if progress is not None:
            progress("poses", 1.0)
        run.stop_note = ses.stop_drives(after_stop=False)
    except StreamStopped as s:
        run.moves.append(s.log)
        run.error = s.error
        run.stop_note = ses.stop_drives(after_stop=True)
    except (GatewayError, SafetyStop) as e:
        run.error = e
        run.stop_note = ses.stop_drives(after_stop=True)
    except KeyboardInterrupt as e:
        run.error = SafetyStop(interrupt_reason(e))
        run.stop_note = ses.stop_drives(after_stop=True)
    except OSError as e:  # the poses so far could not be written (a full disk): stop, drives disabled
        reason = e.strerror or str(e)
        run.error = InputError(f"the measurements could not be written ({reason})", file=e.filename)
        run.stop_note = ses.stop_drives(after_stop=True)
    result.seconds = time.perf_counter() - t_start
    return result


def _settle_and_read(ses: Session, s: CampaignSettings) -> tuple[TrackerSample | None, int]:
    """Read the tracker until valid (bounded), feeding the watchdog throughout. The settling itself
    was streamed (the move's hold); a tracker still seeing motion gets ``tracker_retry_s`` more."""
    beat = 0

    def wait(seconds: float) -> None:
        nonlocal beat
        deadline = time.monotonic() + seconds
        while True:
            raise_if_terminated()
            beat += 1
            ses.client.heartbeat(beat)
            left = deadline - time.monotonic()
            if left <= 0:
                return
            time.sleep(min(left, 0.02))

    for attempt in range(1, s.tracker_attempts + 1):
        sample = ses.client.read_tracker()
        if sample is not None:
            return sample, attempt
        wait(s.tracker_retry_s)
    return None, s.tracker_attempts


def measured_poses(result: CampaignResult, roles: Sequence[str]) -> list[MeasuredPose]:
    """The `rxcomm/Measurements` poses: encoders, tracker position and orientation (NaN when the
    tracker never answered, then ``valid=False``), the pose list's role."""
    out = []
    nan4 = (float("nan"),) * 4
    for r in result.readings:
        t = r.tracker
        out.append(
            MeasuredPose(
                q_rad=r.q_rad.tolist(),
                position_m=tuple(t.position_m.tolist()) if t is not None else (float("nan"),) * 3,
                quaternion_wxyz=tuple(t.quaternion_wxyz.tolist()) if t is not None else nan4,
                valid=t is not None,
                role=roles[r.index],
            )
        )
    return out


def campaign_summary(result: CampaignResult) -> dict[str, object]:
    """Measurements summary (architecture §9: n_poses, n_valid) plus how the campaign went."""
    run = result.run
    lags = [np.nanmax(np.abs(m.following_error)) for m in run.moves if m.n_records]
    err: RxcommError | None = run.error
    return {
        "n_poses": len(result.readings),
        "n_valid": result.n_valid,
        "n_planned": result.n_planned,
        **timing_figures(run.moves),
        "max_move_lag_rad": float(max(lags)) if lags else None,
        "max_tracker_attempts": max((r.attempts for r in result.readings), default=0),
        "interpolation_ratio": run.ratio,
        "outcome": run.outcome,
        "stop_reason": None if err is None else str(err),
        "stop_note": run.stop_note,
        "seconds": result.seconds,
    }


@dataclass(frozen=True)
class CampaignLog:
    """Where and how a campaign's measurements are written (kind `rxcomm/Measurements`)."""

    output: Path
    robot: Robot
    roles: Sequence[str]
    inputs: Mapping[str, str | Path]
    settings: Mapping[str, Any]

    @property
    def part(self) -> Path:
        return self.output.with_name(self.output.name + ".part")

    def measurements(self, camp: CampaignResult, summary: Mapping[str, Any]) -> Measurements:
        return Measurements(
            **Measurements.envelope(self.inputs, self.settings, summary),
            robot=self.robot.name,
            joint_names=list(self.robot.joint_names),
            poses=measured_poses(camp, self.roles),
        )

    def write(self, camp: CampaignResult) -> tuple[Path, dict[str, object]]:
        """The final measurements: ``output`` when the campaign completed (its ``.part`` removed),
        else the ``.part`` with what was measured; returns (the file written, the summary)."""
        summary = campaign_summary(camp)
        written = self.output if camp.run.error is None else self.part
        write_yaml_artefact(written, self.measurements(camp, summary))
        if written == self.output:
            self.part.unlink(missing_ok=True)
        return written, summary


def execute_campaign(
    client: GatewayClient,
    robot: Robot,
    poses: Sequence[Sequence[float]],
    params: DynamicParameters,
    settings: CampaignSettings,
    log: CampaignLog,
    progress: Callable[[str, float], None] | None = None,
) -> CampaignResult:
    """``run_campaign`` with each measured pose on disk as it is taken (``log.part``, summary
    ``outcome: running``: a killed campaign keeps its poses). ``log.write`` writes the result."""

    def on_pose(camp: CampaignResult) -> None:
        running = {"outcome": "running", "stop_reason": "cut off (the run was killed) if still running"}
        write_yaml_artefact(log.part, log.measurements(camp, {**campaign_summary(camp), **running}))

    return run_campaign(client, robot, poses, params, settings, progress, on_pose)
