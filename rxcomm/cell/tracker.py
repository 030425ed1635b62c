"""The simulated tracker: the TCP pose of the *true* robot in the tracker frame, with noise (architecture §6).

This is the only place in the library that applies the truth's geometric errors: the real robot is
the nominal one with `truth.geometry.error_parameters` (an `ErrorModel`) mounted at
`truth.geometry.tracker_to_base`. A reading is the true pose of the TCP (or of `point`, an offset in
the TCP frame, for position-only probes) with Gaussian noise: position N(0, σ_p²) per axis, and
orientation R_meas = exp([n]×)·R_true with n ~ N(0, σ_o²) per axis (tracker frame), σ from
`truth.noise`. With a `visibility` spec (the cell's `TrackerSpec`), poses the tracker cannot see give
`valid=False` readings — the checks of `rxcomm.calibration.pose_selection` on the true robot.

Joint compliance (`truth.geometry.joint_stiffness_nm_per_rad`): the encoders read the motor side, the
link sags under its static holding torque τ(q) (gravity and balancer spring of the TRUE dynamics), so
the tracker sees the arm at q_link = q − τ(q_link)/k per compliant joint (two fixed-point steps: τ
changes by ~1e-3 relative over a deflection of ~1 mrad).

The readings are duck-compatible with `rxcomm.cell.backend.TrackerReading` (`position_m`,
`quaternion_wxyz`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.spatial.transform import Rotation

from rxcomm.cell.truth import loaded_parameters
from rxcomm.errors import InputError
from rxcomm.io.tracker_csv import TrackerExport
from rxcomm.model.dynamics import RobotDynamics
from rxcomm.model.geometric_errors import ErrorModel, measured_pose, placement_to_se3, predict_poses
from rxcomm.model.kinematics import quaternion_wxyz
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import TrackerSpec
from rxcomm.schemas.truth import CellTruth


@dataclass(frozen=True)
class TrackerReading:
    """One tracker sample in the tracker frame. `valid` False: probe not visible (values are then NaN)."""

    position_m: np.ndarray
    rotation: np.ndarray
    valid: bool = True

    @property
    def quaternion_wxyz(self) -> np.ndarray:
        if not self.valid:
            return np.full(4, np.nan)
        return quaternion_wxyz(self.rotation)

    @property
    def se3(self) -> pin.SE3:
        return pin.SE3(self.rotation, self.position_m)


class SimulatedTracker:
    """`measure(q_true)`: what the cell's tracker reports with the robot standing at `q_true`."""

    def __init__(
        self,
        robot_nominal: Robot,
        truth: CellTruth,
        rng: np.random.Generator,
        *,
        visibility: TrackerSpec | None = None,
        point: np.ndarray | None = None,
    ) -> None:
        g = truth.geometry
        self._nominal = robot_nominal
        self._errors = ErrorModel.from_mapping(
            robot_nominal, g.error_parameters, field="geometry.error_parameters"
        )
        self._robot_true = self._errors.apply(robot_nominal)
        self._t2b = placement_to_se3(g.tracker_to_base.xyz_m, g.tracker_to_base.rpy_rad)
        self._sigma_p = truth.noise.tracker_position_sigma_m
        self._sigma_o = truth.noise.tracker_orientation_sigma_rad
        self._rng = rng
        self._visibility = visibility
        self._point = None if point is None else np.asarray(point, dtype=float)
        self._compliance = np.zeros(robot_nominal.n)
        for name, k in g.joint_stiffness_nm_per_rad.items():
            if name not in robot_nominal.joint_names or not k > 0:
                raise InputError(
                    f"{name!r}: needs a joint of {list(robot_nominal.joint_names)} and a stiffness > 0",
                    field="geometry.joint_stiffness_nm_per_rad",
                )
            self._compliance[robot_nominal.joint_names.index(name)] = 1.0 / k
        self._dyn = None
        if np.any(self._compliance):
            self._dyn = RobotDynamics(self._robot_true, loaded_parameters(robot_nominal, truth))

    def link_angles(self, q: np.ndarray) -> np.ndarray:
        """The links' angles with the motors (encoders) at `q`: sagged by the compliance (rad)."""
        q = np.asarray(q, dtype=float)
        if self._dyn is None:
            return q
        q_link = q
        for _ in range(2):
            q_link = q - self._compliance * self._dyn.gravity_torque(q_link)
        return q_link

    def true_pose(self, q: np.ndarray) -> pin.SE3:
        """Noise-free TCP (or point) pose in the tracker frame (tests only: this is the truth)."""
        m = measured_pose(self._robot_true, self.link_angles(q), None, self._t2b)
        if self._point is not None:
            m = pin.SE3(m.rotation, m.act(self._point))
        return m

    def visible(self, q: np.ndarray) -> bool:
        if self._visibility is None:
            return True
        m = self.true_pose(q)
        spec = self._visibility
        p = m.translation
        dist = float(np.linalg.norm(p))
        view = np.asarray(spec.view_axis_in_tracker, dtype=float)
        probe = m.rotation @ np.asarray(spec.probe_axis_in_tcp, dtype=float)
        return (
            spec.range_min_m <= dist <= spec.range_max_m
            and float(view @ p) >= np.cos(spec.half_angle_rad) * np.linalg.norm(view) * dist
            and float(-probe @ p) >= np.cos(spec.probe_half_angle_rad) * np.linalg.norm(probe) * dist
        )

    def measure_many(
        self, qs: np.ndarray, deflection_every: int = 25
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`measure` of many joint states at once (positions [k, 3], rotations [k, 3, 3], visible [k]):
        batched kinematics; the compliance's deflection q − q_link (smooth in the pose) solved every
        `deflection_every` states and interpolated between (µm at 1 kHz samples of a 2 rad/s move)."""
        qs = np.asarray(qs, dtype=float)
        k = len(qs)
        p, r = self.true_poses(qs, deflection_every)
        visible = np.ones(k, dtype=bool)
        if self._visibility is not None:
            spec = self._visibility
            dist = np.linalg.norm(p, axis=1)
            view = np.asarray(spec.view_axis_in_tracker, dtype=float)
            probe = r @ np.asarray(spec.probe_axis_in_tcp, dtype=float)
            visible = (
                (spec.range_min_m <= dist)
                & (dist <= spec.range_max_m)
                & (p @ view >= np.cos(spec.half_angle_rad) * np.linalg.norm(view) * dist)
                & (
                    -np.sum(probe * p, axis=1)
                    >= np.cos(spec.probe_half_angle_rad) * np.linalg.norm(probe, axis=1) * dist
                )
            )
        # One row of 6 draws per sample, so that sample i's noise does not depend on how many samples
        # the batch holds (the export's length varies with when the master asks for it: drawing all
        # positions first gave the same log other orientations on a re-run).
        z = self._rng.standard_normal((k, 6))
        turn = Rotation.from_rotvec(self._sigma_o * z[:, 3:]).as_matrix()
        return p + self._sigma_p * z[:, :3], turn @ r, visible

    def true_poses(self, qs: np.ndarray, deflection_every: int = 25) -> tuple[np.ndarray, np.ndarray]:
        """Noise-free poses (positions [k, 3], rotations [k, 3, 3]) of many states (`measure_many`)."""
        k = len(qs)
        q_link = qs
        if self._dyn is not None and k:
            idx = np.unique(np.append(np.arange(0, k, deflection_every), k - 1))
            defl = np.array([qs[i] - self.link_angles(qs[i]) for i in idx])
            rows = np.arange(k)
            q_link = qs - np.column_stack([np.interp(rows, idx, defl[:, j]) for j in range(qs.shape[1])])
        return predict_poses(self._nominal, q_link, self._errors, self._t2b, point=self._point)

    def measure(self, q_true: np.ndarray) -> TrackerReading:
        """A noisy reading at the true joint angles `q_true` (rad)."""
        if not self.visible(q_true):
            return TrackerReading(np.full(3, np.nan), np.full((3, 3), np.nan), valid=False)
        m = self.true_pose(q_true)
        p = m.translation + self._rng.normal(0.0, self._sigma_p, 3)
        r = pin.exp3(self._rng.normal(0.0, self._sigma_o, 3)) @ m.rotation
        return TrackerReading(p, r, valid=True)


PRETRIGGER_S = 0.25  # s of samples kept before the trigger: the motion's start from rest
PRETRIGGER_KEEP = 4096  # samples collected before a trigger when the old ones are dropped


class MotionTracker:
    """The tracker measuring while the robot moves: the TRUE TCP pose at `rate_hz` on its own clock.

    The cell calls `step(t_s, q)` after every drive cycle with the cell time at the cycle's end and the
    true (motor-side) joint angles; the tracker samples at its instants k / rate_hz, interpolating q
    linearly between the two cycles around each instant (drive cycle 400 µs, tracker 1 ms). Only q
    is kept while the robot runs; `export` turns the samples into poses (true kinematics, compliance,
    noise) at the end, so the cell's cycle stays cheap. Each sample taken at cell time t is stamped
    t + `latency_s` (the tracker reports late); `trigger()` latches the cell time of the stream start
    unstamped (a hardware input). At most `max_samples` are kept (`overflow` says when more came).
    """

    def __init__(
        self,
        tracker: SimulatedTracker,
        rate_hz: float,
        latency_s: float,
        n_axes: int,
        max_samples: int = 1_000_000,
    ) -> None:
        if not rate_hz > 0:
            raise InputError(f"tracker rate {rate_hz} Hz must be > 0", field="tracker.sample_rate_hz")
        self._tracker = tracker
        self.period_s = 1.0 / rate_hz
        self.latency_s = latency_s
        self._max = max_samples
        self._t = np.empty(0)
        self._q = np.empty((0, n_axes))
        self._n = 0
        self._k_next = 0  # index of the next sampling instant on the cell clock
        self._t_prev: float | None = None
        self._q_prev: np.ndarray | None = None
        self.trigger_s: float | None = None
        self.overflow = False

    def trigger(self, t_s: float) -> None:
        """The controller's stream-start trigger at cell time `t_s` (s): latched on the tracker clock;
        a new measurement starts with the last `PRETRIGGER_S` before it (earlier samples dropped)."""
        keep = self._t[: self._n] >= t_s - PRETRIGGER_S
        first = int(np.argmax(keep)) if keep.any() else self._n
        m = self._n - first
        self._t[:m], self._q[:m] = self._t[first : self._n].copy(), self._q[first : self._n].copy()
        self._n = m
        self.overflow = False
        self.trigger_s = float(t_s)

    def step(self, t_s: float, q: np.ndarray) -> None:
        """One drive cycle ended at cell time `t_s` with true joint angles `q` (rad). Before a trigger
        only the last `PRETRIGGER_S` are kept (what the cross-correlation needs of the rest before)."""
        if self.trigger_s is None and self._n >= PRETRIGGER_KEEP:
            self.trigger(self._t[self._n - 1])  # drop the old ones without a trigger latched
            self.trigger_s = None
        if self._t_prev is not None and self._q_prev is not None:
            t0, t1 = self._t_prev, t_s
            k1 = int(np.floor(t1 / self.period_s + 1e-9))
            if k1 >= self._k_next:
                ts = (
                    np.arange(max(self._k_next, int(np.ceil(t0 / self.period_s - 1e-9))), k1 + 1)
                    * self.period_s
                )
                f = ((ts - t0) / (t1 - t0))[:, None]
                self._append(ts, self._q_prev + f * (q - self._q_prev))
                self._k_next = k1 + 1
        self._t_prev, self._q_prev = float(t_s), np.array(q, dtype=float)

    def _append(self, ts: np.ndarray, qs: np.ndarray) -> None:
        room = self._max - self._n
        if len(ts) > room:
            self.overflow = True
            ts, qs = ts[:room], qs[:room]
        if self._n + len(ts) > len(self._t):
            size = min(self._max, max(1024, 2 * len(self._t), self._n + len(ts)))
            t, q = np.empty(size), np.empty((size, self._q.shape[1]))
            t[: self._n], q[: self._n] = self._t[: self._n], self._q[: self._n]
            self._t, self._q = t, q
        self._t[self._n : self._n + len(ts)] = ts
        self._q[self._n : self._n + len(ts)] = qs
        self._n += len(ts)

    def clear(self) -> None:
        """Forget the samples and the trigger."""
        self._n = 0
        self.trigger_s = None
        self.overflow = False

    def export(self) -> TrackerExport:
        """The samples since `PRETRIGGER_S` before the trigger as the tracker exports them: stamps on
        its clock, TCP poses in the tracker frame. Samples the tracker cannot see are left out (a
        real tracker loses the beam)."""
        t, q = self._t[: self._n], self._q[: self._n]
        pos, rot, visible = self._tracker.measure_many(q)
        stamps, pos, rot = t[visible] + self.latency_s, pos[visible], rot[visible]
        quat = Rotation.from_matrix(rot).as_quat()[:, [3, 0, 1, 2]] if len(rot) else np.zeros((0, 4))
        quat = quat * np.where(quat[:, :1] < 0, -1.0, 1.0)  # w ≥ 0, as quaternion_wxyz
        k = len(stamps)
        return TrackerExport(
            np.array(stamps),
            np.array(pos).reshape(k, 3),
            np.array(quat).reshape(k, 4),
            self.trigger_s,
            source="simulated-cell",
        )
