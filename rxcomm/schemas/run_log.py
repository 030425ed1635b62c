"""The summary YAML beside a run log MCAP (``run-log.mcap`` -> ``run-log.yaml``, kind `rxcomm/RunLog`).

`rxcomm run` executes a trajectory on a cell and records, per drive cycle (per setpoint when the
interpolation ratio R > 1), what was commanded and what the drives reported. The MCAP carries the
same envelope as its ``rxcomm/envelope`` metadata record. Topics (times in s from the stream start,
joint side, SI):

- ``/run/joints`` every ``sample_s``: ``q_demand``, ``qd_demand``, ``qdd_demand`` (rad, rad/s, rad/s²,
  the setpoint reached in that cycle), ``q_actual`` (rad, encoders), ``tau_actual`` (N·m, as the drives
  report it), ``tau_ff`` (N·m, the feed-forward sent), ``following_error`` (rad, q_demand − q_actual),
  ``tcp_error_m`` (m, |FK(q_demand) − FK(q_actual)| through the nominal kinematics), ``tcp_speed_m_s``
  (m/s, the planned TCP speed; logs written before it existed are refused by the default reader);
- ``/run/gateway`` once per exchanged block (≈ every 6·R drive cycles): ``status`` (register 30 bits),
  ``error``, ``execute_index``, ``write_index``, ``buffer_level`` (setpoints), ``lead_s``,
  ``round_trip_s``, ``wall_s`` (master clock since the stream start);
- ``/run/tracker`` (optional, when a tracker measured during the motion; `RunLog.tracker` says how):
  ``position_m`` (m, TCP position in the tracker frame), ``quaternion_wxyz`` (TCP orientation in the
  tracker frame), ``t_tracker_s`` (s, the tracker's own time stamp); the message time is the stamp
  aligned to the joint log, t = t_tracker_s − ``tracker.offset_s`` (docs/tracker-csv.md).

For Foxglove's 3D panel, at most ``FOXGLOVE_RATE_HZ`` (every k-th joint sample): ``/run/tf`` and
``/run/tf_demand`` (``foxglove.FrameTransforms``: FK of q_actual with the URDF's link names, FK of
q_demand with the links prefixed ``demand/``) and ``/run/tcp`` and ``/run/tcp_demand``
(``foxglove.PoseInFrame``: the TCP in the root link's frame), ``/robot_description`` (the URDF) and,
with a tracker, ``/run/tracker_pose`` (PoseInFrame in frame ``tracker``); with a calibration,
``/run/tf_tracker`` (the ``tracker`` frame in the root link, once) and the view on the calibrated
robot. Every ``/run/joints``
message repeats the ``joint_names`` (a channel constant). Times are epoch time: the run's wall
clock at its start + the sample time (readers give s from the start).

A run that ends in a stop keeps its log as ``NAME.mcap.part`` (finished, readable; its envelope
summary says ``outcome`` and ``stop_reason``) and writes no ``NAME.yaml``; a drive trip a run was
told is its result (`run --trip-is-result`, settings ``trip_is_result``) is written whole instead.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from rxcomm.schemas.envelope import McapSummary
from rxcomm.schemas.run_settings import RunLogSettings
from rxcomm.schemas.strict import Strict

# The MCAP side of the contract: topics and their fields (unit, meaning).
JOINTS_TOPIC = "/run/joints"
GATEWAY_TOPIC = "/run/gateway"
TRACKER_TOPIC = "/run/tracker"
TF_TOPIC = "/run/tf"
TF_DEMAND_TOPIC = "/run/tf_demand"
TCP_TOPIC = "/run/tcp"
TCP_DEMAND_TOPIC = "/run/tcp_demand"
ROBOT_DESCRIPTION_TOPIC = "/robot_description"  # the URDF text, for the 3D panel's URDF layers
TRACKER_POSE_TOPIC = "/run/tracker_pose"  # foxglove.PoseInFrame of the tracker's TCP, frame "tracker"
TF_TRACKER_TOPIC = "/run/tf_tracker"  # run --calibration: the tracker frame in the root link, once
# Views for Foxglove, derived from the data channels: readers of the data skip them.
FOXGLOVE_VIEW_TOPICS = (
    TF_TOPIC,
    TF_DEMAND_TOPIC,
    TCP_TOPIC,
    TCP_DEMAND_TOPIC,
    ROBOT_DESCRIPTION_TOPIC,
    TRACKER_POSE_TOPIC,
    TF_TRACKER_TOPIC,
)
FOXGLOVE_RATE_HZ = 50.0  # the 3D view's rate: enough to watch, 50x fewer FK calls than 2.5 kHz
JOINT_FIELDS = {
    "q_demand": "rad, position setpoint reached in this cycle",
    "qd_demand": "rad/s, planned joint velocity at that setpoint",
    "qdd_demand": "rad/s², planned joint acceleration at that setpoint",
    "q_actual": "rad, position actual (encoders, joint side)",
    "tau_actual": "N·m, torque actual as reported by the drives (joint side)",
    "tau_ff": "N·m, feed-forward torque sent with the setpoint",
    "following_error": "rad, q_demand − q_actual",
    "tcp_error_m": "m, |FK(q_demand) − FK(q_actual)| of the TCP position, nominal kinematics",
    "tcp_speed_m_s": "m/s, planned TCP speed |J(q_demand)·qd_demand|, nominal kinematics",
}
GATEWAY_FIELDS = {
    "status": "register 30 status bits (docs/gateway.md §2.3)",
    "error": "register 39 error code",
    "execute_index": "setpoints completed",
    "write_index": "setpoints accepted",
    "buffer_level": "setpoints buffered",
    "lead_s": "s, buffered lead = buffer_level · R · cycle",
    "round_trip_s": "s, round trip of the request that brought this reply",
    "wall_s": "s, master wall clock since the stream start",
}

TRACKER_FIELDS = {
    "position_m": "m, TCP position in the tracker frame",
    "quaternion_wxyz": "1, TCP orientation in the tracker frame (w, x, y, z)",
    "t_tracker_s": "s, the tracker's own time stamp (its clock); message time = t_tracker_s − offset_s",
}


class RunLogTopic(Strict):
    topic: str
    period_s: float | None = Field(description="message period, s (None: irregular)")
    n_messages: int = Field(ge=0)
    fields: dict[str, str] = Field(description="field name -> unit and meaning")


class TrackerChannel(Strict):
    """How the ``/run/tracker`` samples were taken and put on the joint log's time axis."""

    source: Literal["simulated-cell", "csv"] = Field(
        description="the simulated cell's tracker during the run, or a real tracker's CSV export"
    )
    source_file: str | None = Field(None, description="the CSV export's file name (source csv)")
    rate_hz: float = Field(gt=0, description="tracker sample rate, Hz (median of the stamps' spacing)")
    n_samples: int = Field(ge=0)
    alignment: Literal["trigger", "cross-correlation", "trigger+cross-correlation"] = Field(
        description="trigger: the stamp of the stream-start trigger; cross-correlation: of the TCP speed "
        "seen by the tracker with the speed of FK(q_actual); trigger+cross-correlation: the trigger, "
        "refined by the cross-correlation (the tracker's latency)"
    )
    offset_s: float = Field(description="s, joint-log time = t_tracker_s − offset_s")
    trigger_offset_s: float | None = Field(
        None, description="s, the offset the trigger alone gave (None: no trigger)"
    )
    correlation: float | None = Field(
        None, description="peak normalised cross-correlation of the speed profiles (None: not used)"
    )


class RunReport(Strict):
    """What both kinds of `run` report in their summaries (a run log, a campaign's measurements): how
    the stream kept time and how the run ended (None: not measured)."""

    underruns: int | str | None = Field(None, description="a count in real time; a note in virtual time")
    cell_overruns: int | str | None = Field(None, description="a count in real time; a note in virtual time")
    interpolation_ratio: int | None = None
    outcome: str | None = None
    stop_reason: str | None = None
    stop_note: str | None = None


class RunLogSummary(RunReport):
    """What a rxcomm/RunLog summary holds (units in the names; None: not measured)."""

    max_lag_rad: list[float | None] | None = Field(description="required; None: not measured")
    rms_lag_rad: list[float | None] | None = Field(description="required; None: not measured")
    max_tcp_error_m: float | None = Field(description="required; None: not measured")
    rms_tcp_error_m: float | None = None
    duration_s: float
    tau_squared_integral_nm2_s: float | None = None
    electrical_energy_j: float | None = None
    sample_s: float | None = None
    n_setpoints: int | None = None
    n_records: int | None = None
    lost_records: int | None = None
    busy_replies: int | None = None
    min_lead_s: float | str | None = Field(None, description="s in real time; a note in virtual time")
    round_trip_probe_p50_s: float | None = None
    round_trip_p50_s: float | None = None
    round_trip_p99_s: float | None = None
    cpu_share: float | None = None
    approach_s: float | None = None
    planned_duration_s: float | None = Field(None, description="while running: the plan's duration")


class RunLog(McapSummary[RunLogSettings, RunLogSummary], kind="rxcomm/RunLog", schema_version=1):
    """Envelope + summary of a run log MCAP, plus how to read it."""

    joint_names: list[str]
    cycle_s: float = Field(gt=0, description="drive cycle of the gateway, s")
    interpolation_ratio: int = Field(ge=1, description="drive cycles per setpoint (R)")
    sample_s: float = Field(gt=0, description="period of /run/joints = R · cycle_s, s")
    feedforward: Literal["identified", "prior", "none"] = Field(
        description="τ_ff source: --dynamics, the robot's prior model, or zeros"
    )
    gateway: str = Field(description="HOST:PORT the run streamed to")
    embedded_cell: bool = Field(description="the gateway was a simulated cell started by `run` itself")
    topics: list[RunLogTopic]
    tracker: TrackerChannel | None = Field(
        None, description="the /run/tracker channel, when a tracker measured during the motion"
    )
