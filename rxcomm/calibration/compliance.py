"""Joint compliance in the calibration's error model: the links sit at q − c·τ, τ the static holding
torque (gravity + balancer) of a dynamics model, c a joint's compliance (rad/(N·m), 1/stiffness).

Which torque model bends the joints matters: the prior (URDF + drives.yaml) misses the truth's
holding torques by a few per cent (13 % at the RX130L's J3), and the fitted compliance then
absorbs that ratio; identified dynamics (`calibrate --dynamics`) remove the bias
(docs/architecture.md, the chain).
"""

from __future__ import annotations

import numpy as np

from rxcomm.model.dynamics import DynamicParameters, RobotDynamics, prior_parameters
from rxcomm.model.robot import Robot

# Compliance parameters are fitted as c·TAU_REF (rad per kN·m, ~1e-3 like the geometric ones).
TAU_REF_NM = 1000.0


def holding_torques(robot: Robot, q: np.ndarray, params: DynamicParameters | None = None) -> np.ndarray:
    """[N, n] static holding torque (gravity + balancer spring), N·m, of `params` (default the PRIOR
    dynamics model): what the joints' transmissions carry at standstill, so what bends them."""
    params = prior_parameters(robot) if params is None else params
    return RobotDynamics(robot, params).gravity_torque(np.atleast_2d(q))


def compliant_joints(tau: np.ndarray) -> tuple[int, ...]:
    """Joints whose holding torque matters (≥ 20 % of the largest) and varies over the poses [N, n] N·m:
    the candidates for a compliance parameter (others cannot be told from a joint offset)."""
    peak = np.max(np.abs(tau), axis=0)
    return tuple(int(j) for j in np.flatnonzero((peak >= 0.2 * peak.max()) & (np.ptp(tau, axis=0) > 1.0)))
