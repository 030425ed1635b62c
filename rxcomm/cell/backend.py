"""What the gateway server drives each 400 µs cycle: the interface to the cell's physics.

The server owns the protocol, the CiA 402 state machines, setpoint interpolation and the quick-stop
ramp; a backend owns the drives' control loops, the robot plant and the tracker. The server calls
``cycle`` once per drive cycle with the position demand (rad, motor side already divided out: joint
angles), the feed-forward torque (N·m, 0x60B2 semantics: added after the velocity loop) and which
axes have torque on. Disabled axes are held by their brakes; what that means is the backend's call.

Calls are serialised by the server (never concurrent): ``cycle`` from its cycle thread, ``tracker``
and ``feedback`` from its Modbus thread. Arrays passed in are fresh copies the backend may keep.

``IdealBackend`` is a protocol test double (actual = demand, torque = feed-forward): it lets the
gateway be tested without physics and must not be used to judge control performance. It and the
simulated cell (`rxcomm.cell.sim.SimulatedCell`) derive from ``BackendState``, which keeps the
backend's constants, its latest feedback and the cycle count.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class AxisFeedback:
    """Drive feedback after one cycle, per axis (shape (n_axes,) each)."""

    position_rad: np.ndarray
    velocity_rad_s: np.ndarray
    torque_nm: np.ndarray
    following_error_rad: np.ndarray  # demand - actual, as the drive computes it


@dataclass(frozen=True)
class TrackerReading:
    """One tracker sample of the TCP in the tracker frame."""

    position_m: np.ndarray  # (3,)
    quaternion_wxyz: np.ndarray  # (4,), unit


@runtime_checkable
class CellBackend(Protocol):
    """The physics behind the gateway. All arrays have shape (n_axes,)."""

    @property
    def n_axes(self) -> int: ...

    @property
    def cycle_s(self) -> float:
        """Drive cycle the backend integrates per ``cycle`` call (400e-6 for map v1)."""
        ...

    @property
    def rated_torque_nm(self) -> np.ndarray: ...

    @property
    def following_error_limit_rad(self) -> np.ndarray:
        """The server faults an enabled axis (0x8611) when |following error| exceeds this."""
        ...

    @property
    def quick_stop_decel_rad_s2(self) -> np.ndarray:
        """Deceleration of the quick-stop / fault-reaction ramp the server feeds as demand."""
        ...

    def feedback(self) -> AxisFeedback:
        """The latest feedback without advancing time (the initial state before any cycle)."""
        ...

    def cycle(
        self, position_demand_rad: np.ndarray, torque_ff_nm: np.ndarray, enabled: np.ndarray
    ) -> AxisFeedback:
        """Advance one drive cycle and return the feedback at its end."""
        ...

    def tracker(self) -> TrackerReading | None:
        """A tracker sample, or None when the robot is moving or the probe is not visible."""
        ...


class BackendState:
    """What every backend keeps, whatever its physics: the constants of `CellBackend` (the axis count
    is that of the initial positions), the latest feedback (before the first cycle: at rest at the
    initial positions) and the cycles run."""

    def __init__(
        self,
        position_rad: np.ndarray,
        *,
        cycle_s: float,
        rated_torque_nm: np.ndarray,
        following_error_limit_rad: np.ndarray,
        quick_stop_decel_rad_s2: np.ndarray,
    ) -> None:
        self._n = len(position_rad)
        self._dt = cycle_s
        self._rated = rated_torque_nm
        self._fe_limit = following_error_limit_rad
        self._qs_decel = quick_stop_decel_rad_s2
        zero = np.zeros(self._n)
        self._fb = AxisFeedback(position_rad, zero, zero, zero)
        self.cycles = 0

    @property
    def n_axes(self) -> int:
        return self._n

    @property
    def cycle_s(self) -> float:
        return self._dt

    @property
    def rated_torque_nm(self) -> np.ndarray:
        return self._rated

    @property
    def following_error_limit_rad(self) -> np.ndarray:
        return self._fe_limit

    @property
    def quick_stop_decel_rad_s2(self) -> np.ndarray:
        return self._qs_decel

    def feedback(self) -> AxisFeedback:
        return self._fb


class IdealBackend(BackendState):
    """Protocol test backend: positions follow the demand exactly, torque equals feed-forward.

    The tracker reports a fixed function of the joint positions (a rigid pseudo-TCP) when every
    axis stood still during the last cycle, so tests can check the tracker path end to end.
    """

    def __init__(
        self,
        q0_rad: np.ndarray | None = None,
        *,
        n_axes: int = 6,
        cycle_s: float = 400e-6,
        rated_torque_nm: np.ndarray | None = None,
        following_error_limit_rad: float = 0.05,
        quick_stop_decel_rad_s2: float = 50.0,
    ):
        self._q = np.zeros(n_axes) if q0_rad is None else np.array(q0_rad, dtype=float)
        if self._q.shape != (n_axes,):
            raise ValueError(f"q0_rad must have shape ({n_axes},)")
        super().__init__(
            self._q.copy(),
            cycle_s=cycle_s,
            rated_torque_nm=(
                np.array([180.0, 180.0, 90.0, 30.0, 30.0, 15.0])[:n_axes]
                if rated_torque_nm is None
                else np.asarray(rated_torque_nm, dtype=float)
            ),
            following_error_limit_rad=np.full(n_axes, following_error_limit_rad),
            quick_stop_decel_rad_s2=np.full(n_axes, quick_stop_decel_rad_s2),
        )

    def cycle(
        self, position_demand_rad: np.ndarray, torque_ff_nm: np.ndarray, enabled: np.ndarray
    ) -> AxisFeedback:
        # Brakes hold disabled axes where they are.
        q_new = np.where(enabled, position_demand_rad, self._q)
        v = (q_new - self._q) / self._dt
        tau = np.where(enabled, torque_ff_nm, 0.0)
        self._q = q_new
        self._fb = AxisFeedback(q_new.copy(), v, tau, np.zeros(self._n))
        self.cycles += 1
        return self._fb

    def tracker(self) -> TrackerReading | None:
        if np.any(self._fb.velocity_rad_s != 0.0):
            return None
        q = self._q
        # A smooth, injective-enough map so a test can tell poses apart; not a robot model.
        pos = np.array([1.0 + 0.1 * np.sin(q[0]), 0.1 * np.sin(q[1]), 0.5 + 0.1 * np.sin(q[2])])
        half = 0.5 * q[min(5, self._n - 1)]
        return TrackerReading(pos, np.array([np.cos(half), 0.0, 0.0, np.sin(half)]))
