"""The run log: ``NAME.mcap`` (Foxglove-plottable time series) + ``NAME.yaml`` (kind `rxcomm/RunLog`).

The contract `identify` reads (see ``rxcomm.schemas.run_log``): ``/run/joints`` at the setpoint rate
(the drive cycle when R = 1) and ``/run/gateway`` once per block reply. Written after the motion from
the arrays the session kept in memory. A run that ended in a stop keeps ``NAME.mcap.part``: a finished,
readable MCAP whose envelope summary says ``outcome`` and ``stop_reason``; no ``NAME.yaml``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from rxcomm.execution.session import RunResult, StreamLog
from rxcomm.io.mcap_io import McapWriter, number_field, vector_field
from rxcomm.io.yaml_io import summary_yaml_path, write_summary_yaml
from rxcomm.model.kinematics import frame_placement
from rxcomm.model.robot import Robot
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.run_log import (
    GATEWAY_FIELDS,
    GATEWAY_TOPIC,
    JOINT_FIELDS,
    JOINTS_TOPIC,
    RunLog,
    RunLogTopic,
)


def tcp_errors(robot: Robot, q_demand: np.ndarray, q_actual: np.ndarray) -> np.ndarray:
    """Per sample |p_tcp(q_demand) − p_tcp(q_actual)| (m), nominal kinematics; NaN rows stay NaN."""
    data = robot.create_data()
    out = np.full(len(q_demand), np.nan)
    for i, (qd, qa) in enumerate(zip(q_demand, q_actual, strict=True)):
        if np.all(np.isfinite(qa)):
            p_d = frame_placement(robot, data, qd, robot.tcp_frame_id).translation
            p_a = frame_placement(robot, data, qa, robot.tcp_frame_id).translation
            out[i] = float(np.linalg.norm(p_d - p_a))
    return out


def _nanmax(a: np.ndarray, axis: int | None = None) -> Any:
    if a.size == 0 or np.all(np.isnan(a)):
        return None if axis is None else [None] * a.shape[1]
    return np.nanmax(a, axis=axis).tolist()


def _percentile(a: np.ndarray, q: float) -> float | None:
    return float(np.percentile(a, q)) if len(a) else None


def run_summary(robot: Robot, result: RunResult, tcp_error: np.ndarray | None = None) -> dict[str, Any]:
    """The run-log summary of architecture §9 (underruns, max/rms lag per joint, max TCP error, duration)."""
    log = result.log
    approach = result.approach
    streams = [s for s in (approach, log) if s is not None]
    out: dict[str, Any] = {"underruns": int(sum(s.underruns for s in streams))}
    if log is not None and log.n_records:
        fe = np.abs(log.following_error)
        tcp = tcp_errors(robot, log.q_demand, log.q_actual) if tcp_error is None else tcp_error
        out |= {
            "max_lag_rad": _nanmax(fe, axis=0),
            "rms_lag_rad": np.sqrt(np.nanmean(fe**2, axis=0)).tolist(),
            "max_tcp_error_m": _nanmax(tcp),
            "rms_tcp_error_m": float(np.sqrt(np.nanmean(tcp**2))),
            "duration_s": (log.n_records - 1) * log.plan.sample_s,
        }
    else:
        # Nothing was recorded (stopped before the first trace record): not measured, not zero.
        out |= {"max_lag_rad": None, "rms_lag_rad": None, "max_tcp_error_m": None, "duration_s": 0.0}
    out |= {
        "outcome": result.outcome,
        "stop_reason": None if result.error is None else str(result.error),
        "stop_note": result.stop_note,
        "interpolation_ratio": result.ratio,
        "sample_s": result.ratio * result.cycle_s,
        "n_setpoints": 0 if log is None else log.plan.n,
        "n_records": 0 if log is None else log.n_records,
        "lost_records": 0 if log is None else log.lost_records,
        "busy_replies": 0 if log is None else log.busy_replies,
        "min_lead_s": None if log is None else _finite_or_none(log.min_lead_s()),
        "round_trip_probe_p50_s": _percentile(result.round_trip_probe_s, 50),
        "round_trip_p50_s": None if log is None else _percentile(log.round_trips_s, 50),
        "round_trip_p99_s": None if log is None else _percentile(log.round_trips_s, 99),
        "cpu_share": None if log is None or log.wall_s <= 0 else log.cpu_s / log.wall_s,
        "approach_s": 0.0 if approach is None else approach.plan.duration_s,
    }
    return out


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def joint_columns(robot: Robot, log: StreamLog, tcp_error: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The ``/run/joints`` columns of a stream log (one row per trace record)."""
    m = log.n_records
    p = log.plan
    return {
        "q_demand": p.q[:m],
        "qd_demand": p.qd[:m],
        "qdd_demand": p.qdd[:m],
        "q_actual": log.q_actual,
        "tau_actual": log.tau_actual,
        "tau_ff": p.tau_ff[:m],
        "following_error": log.following_error,
        "tcp_error_m": tcp_errors(robot, p.q[:m], log.q_actual) if tcp_error is None else tcp_error,
    }


def write_run_log(
    path: str | Path,
    robot: Robot,
    result: RunResult,
    *,
    inputs: Mapping[str, str | Path],
    settings: Mapping[str, Any],
    feedforward: str,
    embedded_cell: bool,
) -> tuple[Path, dict[str, Any]]:
    """Write the log of ``result``; returns (the file written, the summary).

    Completed: ``NAME.mcap`` + ``NAME.yaml``. Stopped: ``NAME.mcap.part`` only (finished, readable).
    """
    path = Path(path)
    summary_yaml_path(path)  # refuses a name not ending in .mcap before anything is written
    log = result.log
    tcp = None
    if log is not None:
        tcp = tcp_errors(robot, log.q_demand, log.q_actual)
    summary = run_summary(robot, result, tcp)
    env = RunLog.envelope(dict(inputs), dict(settings), summary)
    sample_s = result.ratio * result.cycle_s
    n_joint = 0 if log is None else log.n_records
    n_gw = 0 if log is None else len(log.gateway["t"])
    data = {
        **env,
        "mcap_file": path.name,
        "mcap_sha256": "0" * 64,
        "joint_names": list(robot.joint_names),
        "cycle_s": result.cycle_s,
        "interpolation_ratio": result.ratio,
        "sample_s": sample_s,
        "feedforward": feedforward,
        "gateway": result.gateway,
        "embedded_cell": embedded_cell,
        "topics": [
            RunLogTopic(topic=JOINTS_TOPIC, period_s=sample_s, n_messages=n_joint, fields=JOINT_FIELDS),
            RunLogTopic(topic=GATEWAY_TOPIC, period_s=None, n_messages=n_gw, fields=GATEWAY_FIELDS),
        ],
    }
    RunLog.model_validate(data)  # a bad summary fails before anything is written

    def write_yaml(part: Path) -> None:
        write_summary_yaml(path, RunLog.model_validate({**data, "mcap_sha256": sha256_file(part)}))

    w = McapWriter(path, env)
    try:
        # Channels first, with units in the schema, so even a log stopped before its first record has them.
        w.add_channel(JOINTS_TOPIC, "rxcomm.RunJoints", _joint_schema(robot.n))
        w.add_channel(GATEWAY_TOPIC, "rxcomm.RunGateway", _gateway_schema())
        if log is not None:
            t = np.arange(log.n_records) * log.plan.sample_s
            w.write_arrays(JOINTS_TOPIC, t, joint_columns(robot, log, tcp), digits=10)
            g = log.gateway
            w.write_arrays(GATEWAY_TOPIC, g["t"], {k: g[k] for k in GATEWAY_FIELDS}, digits=10)
    except BaseException:
        w.abort()
        raise
    if result.error is not None:
        return w.abort(), summary
    return w.finish(before_rename=write_yaml), summary


def _joint_schema(n: int) -> dict[str, dict[str, Any]]:
    return {k: number_field(d) if k == "tcp_error_m" else vector_field(n, d) for k, d in JOINT_FIELDS.items()}


def _gateway_schema() -> dict[str, dict[str, Any]]:
    floats = ("lead_s", "round_trip_s", "wall_s")
    return {
        k: number_field(d) if k in floats else {"type": "integer", "description": d}
        for k, d in GATEWAY_FIELDS.items()
    }
