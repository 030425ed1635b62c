"""Commanding the links where the calibrated model wants them: the joint compliance (issue 17).

With the error model "full+compliance" the calibration found that J2/J3 deflect under their holding
torque: the link angle is q_link = q − c·τ(q) (q the encoder angle, c the compliance in rad/(N·m),
τ the holding torque of the model the fit used: `compliance_torque_model`, rxcomm.calibration.artefact).
`encoder_angles` inverts that for a pose held at rest, so the commissioned state commands the
encoder angles that put the links at the IK solution of the calibrated kinematics. A motion's
dynamic torques deflect the links too; that part is not compensated here.
"""

from __future__ import annotations

import numpy as np

from rxcomm.calibration.compliance import holding_torques
from rxcomm.errors import InputError
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot
from rxcomm.schemas.calibration import Calibration


def joint_compliance(robot: Robot, calibration: Calibration) -> np.ndarray:
    """Per joint c (rad/(N·m)) of the calibration's chosen model; zeros when it is rigid."""
    c = np.zeros(robot.n)
    for e in calibration.compliance:
        if e.joint not in robot.joint_names:
            raise InputError(f"compliance of an unknown joint {e.joint!r}", field="compliance")
        c[robot.joint_names.index(e.joint)] = e.compliance_rad_per_nm
    return c


def compliance_torque_params(
    calibration: Calibration, identified: DynamicParameters | None
) -> DynamicParameters | None:
    """The torque model the compliance was fitted with: the identified one (must be given) or the
    prior (None)."""
    if calibration.settings.get("compliance_torque_model") != "identified":
        return None
    if identified is None:
        raise InputError(
            "the calibration's compliance was fitted with identified torques: give --dynamics",
            field="dynamics",
        )
    return identified


def encoder_angles(
    robot: Robot,
    q_link: np.ndarray,
    compliance: np.ndarray,
    params: DynamicParameters | None = None,
    iterations: int = 5,
) -> np.ndarray:
    """The encoder angles q with q − c·τ(q) = q_link at rest (fixed point: c·∂τ/∂q ≪ 1)."""
    q_link = np.asarray(q_link, float)
    q = q_link.copy()
    if not np.any(compliance):
        return q
    for _ in range(iterations):
        q = q_link + compliance * holding_torques(robot, q, params)[0]
    return q
