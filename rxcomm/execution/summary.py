"""The run summary (architecture §9) and the motion figures it is made of, kept as running values.

``run_summary`` is the summary of a ``RunResult``. Its motion figures (max/rms lag per joint, max/rms
TCP error, duration, ∫τᵀτ dt and the electrical energy of ``rxcomm.model.energy``) come either from
the records a ``StreamLog`` holds or from a ``MotionStats``: the running maxima, sums of squares
and energy integrals the log writer updates with every chunk it writes, so the master does not keep
the records of a long run (``rxcomm.execution.records``). ``MotionStats`` computes what the array
formulas compute — the same central differences for the joint speeds (np.gradient on the finite
rows), the same trapezoids — so both agree to rounding (tests/test_bounded_memory.py).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin

from rxcomm.execution.records import NOT_APPLICABLE_VIRTUAL, RunResult, timing_figures
from rxcomm.model.batch_kinematics import serial_chain, tcp_positions
from rxcomm.model.energy import electrical_power, motion_energy
from rxcomm.model.kinematics import frame_placement
from rxcomm.model.robot import Robot


def tcp_errors(robot: Robot, q_demand: np.ndarray, q_actual: np.ndarray) -> np.ndarray:
    """Per sample |p_tcp(q_demand) − p_tcp(q_actual)| (m), nominal kinematics; NaN rows stay NaN."""
    if serial_chain(robot) is not None:  # the writer's batch FK, so both give the same figures
        q_demand = np.asarray(q_demand, dtype=float)
        return tcp_error_and_speed(robot, q_demand, np.zeros_like(q_demand), np.asarray(q_actual))[0]
    data = robot.create_data()
    out = np.full(len(q_demand), np.nan)
    for i, (qd, qa) in enumerate(zip(q_demand, q_actual, strict=True)):
        if np.all(np.isfinite(qa)):
            p_d = frame_placement(robot, data, qd, robot.tcp_frame_id).translation
            p_a = frame_placement(robot, data, qa, robot.tcp_frame_id).translation
            out[i] = float(np.linalg.norm(p_d - p_a))
    return out


def tcp_error_and_speed(
    robot: Robot, q_demand: np.ndarray, qd_demand: np.ndarray, q_actual: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per sample (m) ``tcp_errors`` and (m/s) the planned TCP speed |v(q_demand, qd_demand)|, with one
    kinematics pass per side (the demand pass carries the velocity): the writer does this while the
    robot moves, so it counts: a serial chain of revolute joints goes through the numpy batch FK)."""
    chain = serial_chain(robot)
    if chain is not None:
        p_d, v = tcp_positions(chain, q_demand, qd_demand)
        assert v is not None
        ok = np.all(np.isfinite(q_actual), axis=1)
        err = np.full(len(q_demand), np.nan)
        if ok.any():
            p_a, _ = tcp_positions(chain, q_actual[ok])
            err[ok] = np.linalg.norm(p_d[ok] - p_a, axis=1)
        return err, np.linalg.norm(v, axis=1)
    model, data, fid = robot.model, robot.create_data(), robot.tcp_frame_id
    err = np.full(len(q_demand), np.nan)
    speed = np.zeros(len(q_demand))
    frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    for i in range(len(q_demand)):
        pin.forwardKinematics(model, data, q_demand[i], qd_demand[i])
        speed[i] = float(np.linalg.norm(pin.getFrameVelocity(model, data, fid, frame).linear))
        if np.all(np.isfinite(q_actual[i])):
            p_d = pin.updateFramePlacement(model, data, fid).translation.copy()
            pin.forwardKinematics(model, data, q_actual[i])
            err[i] = float(np.linalg.norm(p_d - pin.updateFramePlacement(model, data, fid).translation))
    return err, speed


def _nanmax(a: np.ndarray, axis: int | None = None) -> Any:
    if a.size == 0 or np.all(np.isnan(a)):
        return None if axis is None else [None] * a.shape[1]
    return np.nanmax(a, axis=axis).tolist()


def _percentile(a: np.ndarray, q: float) -> float | None:
    return float(np.percentile(a, q)) if len(a) else None


def run_summary(
    robot: Robot,
    result: RunResult,
    tcp_error: np.ndarray | None = None,
    motion: MotionStats | None = None,
) -> dict[str, Any]:
    """The run-log summary of architecture §9 (underruns, max/rms lag per joint, max TCP error, duration).

    The motion figures come from ``motion`` (the running values the log writer kept of every record
    it wrote) or, without it, from the records ``result.log`` holds (with ``tcp_error`` per record,
    else computed)."""
    log = result.log
    approach = result.approach
    streams = [s for s in (approach, log) if s is not None]
    virtual = any(s.virtual_time for s in streams)
    out: dict[str, Any] = dict(timing_figures(streams))
    if log is not None and motion is not None and motion.n:
        out |= motion.figures()
    elif log is not None and log.n_records and motion is None:
        if log.records_in_sink:
            raise ValueError("the log's records went to a sink: pass its MotionStats")
        fe = np.abs(log.following_error)
        tcp = tcp_errors(robot, log.q_demand, log.q_actual) if tcp_error is None else tcp_error
        out |= {
            "max_lag_rad": _nanmax(fe, axis=0),
            "rms_lag_rad": np.sqrt(np.nanmean(fe**2, axis=0)).tolist(),
            "max_tcp_error_m": _nanmax(tcp),
            "rms_tcp_error_m": float(np.sqrt(np.nanmean(tcp**2))),
            "duration_s": (log.n_records - 1) * log.plan.sample_s,
            # from the measured torques and encoder positions of the recorded motion (approach excluded)
            **motion_energy(
                robot, np.arange(log.n_records) * log.plan.sample_s, log.q_actual, log.tau_actual
            ),
        }
    else:
        # Nothing was recorded (stopped before the first trace record): not measured, not zero.
        out |= {
            "max_lag_rad": None,
            "rms_lag_rad": None,
            "max_tcp_error_m": None,
            "duration_s": 0.0,
            "tau_squared_integral_nm2_s": None,
            "electrical_energy_j": None,
        }
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
        "min_lead_s": NOT_APPLICABLE_VIRTUAL
        if virtual
        else (None if log is None else _finite_or_none(log.min_lead_s())),
        "round_trip_probe_p50_s": _percentile(result.round_trip_probe_s, 50),
        "round_trip_p50_s": None if log is None else _percentile(log.round_trips_s, 50),
        "round_trip_p99_s": None if log is None else _percentile(log.round_trips_s, 99),
        "cpu_share": None if log is None or log.wall_s <= 0 else log.cpu_s / log.wall_s,
        "approach_s": 0.0 if approach is None else approach.plan.duration_s,
    }
    return out


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


class MotionStats:
    """Running motion figures over consecutive chunks of records (``add``), as ``run_summary``
    computes them from whole arrays: NaN rows (lost records) are left out, as there."""

    def __init__(self, robot: Robot, sample_s: float) -> None:
        self.robot, self.sample_s = robot, float(sample_s)
        n = robot.n
        self.n = 0  # records seen
        self._lag_max = np.full(n, -np.inf)
        self._lag_sq = np.zeros(n)
        self._lag_count = np.zeros(n, dtype=np.int64)
        self._tcp_max = -np.inf
        self._tcp_sq = 0.0
        self._tcp_count = 0
        self._energy = _EnergyIntegrals(robot)

    def add(
        self,
        first: int,
        q_demand: np.ndarray,
        q_actual: np.ndarray,
        tau_actual: np.ndarray,
        tcp_error: np.ndarray,
    ) -> None:
        """Records ``first…first + len − 1`` (consecutive with those added before)."""
        if first != self.n:
            raise ValueError(f"records must be consecutive: got {first}, expected {self.n}")
        m = len(q_actual)
        if m == 0:
            return
        fe = np.abs(q_demand - q_actual)
        ok = ~np.isnan(fe)
        self._lag_max = np.maximum(self._lag_max, np.where(ok, fe, -np.inf).max(axis=0))
        self._lag_sq += np.where(ok, fe**2, 0.0).sum(axis=0)
        self._lag_count += ok.sum(axis=0)
        tcp = np.asarray(tcp_error, dtype=float)
        tok = ~np.isnan(tcp)
        if tok.any():
            self._tcp_max = max(self._tcp_max, float(tcp[tok].max()))
            self._tcp_sq += float(np.sum(tcp[tok] ** 2))
            self._tcp_count += int(tok.sum())
        self._energy.add(np.arange(first, first + m) * self.sample_s, q_actual, tau_actual)
        self.n += m

    def figures(self) -> dict[str, Any]:
        """The summary's motion fields (as ``run_summary`` names them)."""
        none = self._lag_count == 0
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt(self._lag_sq / self._lag_count)
        return {
            "max_lag_rad": [None] * len(none) if none.all() else self._lag_max.tolist(),
            "rms_lag_rad": rms.tolist(),
            "max_tcp_error_m": None if self._tcp_count == 0 else self._tcp_max,
            "rms_tcp_error_m": float(np.sqrt(self._tcp_sq / self._tcp_count))
            if self._tcp_count
            else float("nan"),
            "duration_s": (self.n - 1) * self.sample_s,
            **self._energy.figures(),
        }


class _EnergyIntegrals:
    """``motion_energy`` over chunks: the speeds by np.gradient's central differences on the finite
    rows (one-sided at both ends), ∫τᵀτ dt and ∫max(P, 0) dt by trapezoids. Keeps the last two finite
    rows: a row's speed needs its successor."""

    def __init__(self, robot: Robot) -> None:
        self.robot = robot
        n = robot.n
        self._t = np.zeros(0)
        self._q = np.zeros((0, n))
        self._tau = np.zeros((0, n))
        self._done = 0  # leading rows of the carry whose speed is computed (0 or 1)
        self._rows = 0  # finite rows seen
        self._last: tuple[float, float, float] | None = None  # (t, τᵀτ, max(P, 0)) of the last row done
        self._tau2 = 0.0
        self._elec: float | None = 0.0

    def add(self, t: np.ndarray, q: np.ndarray, tau: np.ndarray) -> None:
        keep = np.isfinite(t) & np.all(np.isfinite(q), axis=1) & np.all(np.isfinite(tau), axis=1)
        if not keep.any():
            return
        self._rows += int(keep.sum())
        t = np.concatenate([self._t, t[keep]])
        q = np.concatenate([self._q, q[keep]])
        tau = np.concatenate([self._tau, tau[keep]])
        lo, hi = self._done, len(t) - 1  # rows lo…hi−1 have a successor: their speed is known
        if hi > lo:
            qd = np.empty((hi - lo, q.shape[1]))
            j0 = lo
            if lo == 0:  # the first finite row of the stream: forward difference
                qd[0] = (q[1] - q[0]) / (t[1] - t[0])
                j0 = 1
            if hi > j0:
                dx1 = (t[j0:hi] - t[j0 - 1 : hi - 1])[:, None]
                dx2 = (t[j0 + 1 : hi + 1] - t[j0:hi])[:, None]
                a = -(dx2) / (dx1 * (dx1 + dx2))
                b = (dx2 - dx1) / (dx1 * dx2)
                c = dx1 / (dx2 * (dx1 + dx2))
                qd[j0 - lo :] = a * q[j0 - 1 : hi - 1] + b * q[j0:hi] + c * q[j0 + 1 : hi + 1]
            self._integrate(t[lo:hi], qd, tau[lo:hi])
        keep_from = max(len(t) - 2, 0)
        self._t, self._q, self._tau = t[keep_from:], q[keep_from:], tau[keep_from:]
        self._done = 1 if self._last is not None and len(self._t) == 2 else 0

    def _integrate(self, t: np.ndarray, qd: np.ndarray, tau: np.ndarray) -> None:
        s = np.sum(tau**2, axis=1)
        p = electrical_power(self.robot, qd, tau)
        pp = np.maximum(p, 0.0) if p is not None else np.zeros(len(t))
        if self._last is not None:
            t = np.concatenate([[self._last[0]], t])
            s = np.concatenate([[self._last[1]], s])
            pp = np.concatenate([[self._last[2]], pp])
        if len(t) >= 2:
            d = np.diff(t)
            self._tau2 += float(np.add.reduce(d * (s[1:] + s[:-1]) / 2.0))
            if p is not None and self._elec is not None:
                self._elec += float(np.add.reduce(d * (pp[1:] + pp[:-1]) / 2.0))
        if p is None:
            self._elec = None
        self._last = (float(t[-1]), float(s[-1]), float(pp[-1]))

    def figures(self) -> dict[str, float | None]:
        """The energy fields; the last finite row (backward difference) is counted here, not kept."""
        known = electrical_power(self.robot, np.zeros((1, self.robot.n)), np.zeros((1, self.robot.n)))
        if self._rows < 2:
            return {"tau_squared_integral_nm2_s": 0.0, "electrical_energy_j": None if known is None else 0.0}
        tau2, elec, last = self._tau2, self._elec, self._last
        t, q, tau = self._t, self._q, self._tau
        qd = (q[-1] - q[-2]) / (t[-1] - t[-2])
        s = float(np.sum(tau[-1] ** 2))
        p = electrical_power(self.robot, qd[None, :], tau[-1:])
        assert last is not None
        d = t[-1] - last[0]
        tau2 += float(d * (last[1] + s) / 2.0)
        if p is not None and elec is not None:
            elec += float(d * (last[2] + max(float(p[0]), 0.0)) / 2.0)
        return {"tau_squared_integral_nm2_s": tau2, "electrical_energy_j": None if p is None else elec}
