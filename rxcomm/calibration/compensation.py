"""Commanding the links where the calibrated model wants them: the joint compliance (issue 17).

With the error model "full+compliance" the calibration found that J2/J3 deflect under their holding
torque: the link angle is q_link = q − c·τ(q) (q the encoder angle, c the compliance in rad/(N·m),
τ the holding torque of the model the fit used: `compliance_torque_model`, rxcomm.calibration.artefact).
`encoder_angles` inverts that (one pose or many), so the commissioned state commands the encoder
angles that put the links at the IK solution of the calibrated kinematics: `plan-poses` for the ISO
pose cycle, `plan-cp` for CP paths (`compliance_command` gives the planners the map as a function:
the planning layer does not import the calibration). A motion's dynamic torques deflect the links
too; that part is not compensated (docs/architecture.md, the ISO paragraph, says how much it is).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rxcomm.errors import InputError
from rxcomm.model.dynamics import DynamicParameters, RobotDynamics, prior_parameters
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
    """The torque model the compliance was fitted with (the artefact's summary, `calibrate` writes it
    there): the identified one (must be given) or the prior (None)."""
    if calibration.summary.compliance_torque_model != "identified":
        return None
    if identified is None:
        raise InputError(
            "the calibration's compliance was fitted with identified torques: give --dynamics",
            field="dynamics",
        )
    return identified


def encoder_map(
    robot: Robot, compliance: np.ndarray, params: DynamicParameters | None = None, iterations: int = 5
) -> Callable[[np.ndarray], np.ndarray]:
    """q_link ↦ the encoder angles q with q − c·τ(q) = q_link at rest, for one pose [n] or many
    [N, n] (fixed point: c·∂τ/∂q ~ 1e-3, so five steps leave ~1e-15 rad). τ is the static holding
    torque (gravity + balancer) of `params` (default the prior) on the nominal `robot`."""
    compliance = np.asarray(compliance, float)
    dyn = RobotDynamics(robot, prior_parameters(robot) if params is None else params)

    def encoder(q_link: np.ndarray) -> np.ndarray:
        q_link = np.asarray(q_link, float)
        q = q_link.copy()
        if not np.any(compliance):
            return q
        for _ in range(iterations):
            q = q_link + compliance * dyn.gravity_torque(q)
        return q

    return encoder


def encoder_angles(
    robot: Robot,
    q_link: np.ndarray,
    compliance: np.ndarray,
    params: DynamicParameters | None = None,
    iterations: int = 5,
) -> np.ndarray:
    """The encoder angles q with q − c·τ(q) = q_link at rest (`encoder_map` of one pose or many)."""
    return encoder_map(robot, compliance, params, iterations)(q_link)


def compliance_command(
    robot: Robot, calibration: Calibration, identified: DynamicParameters | None
) -> tuple[Callable[[np.ndarray], np.ndarray] | None, list[float] | None]:
    """For a calibration whose chosen model found joint compliance: the map link → encoder angles on
    the nominal `robot` (the torque model the fit used) and the compliances (rad/(N·m)) to record;
    for a rigid one (None, None)."""
    c = joint_compliance(robot, calibration)
    if not c.any():
        return None, None
    return encoder_map(robot, c, compliance_torque_params(calibration, identified)), c.tolist()
