"""A payload on the flange as part of the last link's inertial parameters (architecture §7 identify-payload).

A rigid load (mass m, centre of mass c in the flange frame, inertia I_c about c in flange axes) moves
with the last link, so the arm carrying it is the same arm with the load's 10 inertial parameters
(Pinocchio's m, m·c, inertia about the joint origin, in the last joint's frame) added to the last
link's: τ = Y(q, q̇, q̈)·(p + δp), and δp enters only through the last link's 10 regressor columns
(`last_link_columns`), which is why the payload is linear in the torque residual τ − Y·p.

The flange is the TCP's parent frame (`drives.yaml` tool.parent_frame); it must be on the last link.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.model.dynamics import DynamicParameters
from rxcomm.model.robot import Robot
from rxcomm.schemas.payload import Inertia6, Payload, PayloadMount, inertia_matrix


@dataclass(frozen=True)
class FlangeInertia:
    """A payload in flange terms: mass (kg), centre of mass (m), inertia about it (3 × 3, kg·m²)."""

    mass_kg: float
    com_m: np.ndarray
    inertia_com_kgm2: np.ndarray

    @classmethod
    def of_mount(cls, mount: PayloadMount) -> FlangeInertia:
        return cls(mount.mass_kg, np.array(mount.com_m, float), inertia_matrix(mount.inertia_com_kgm2))

    @property
    def inertia6(self) -> Inertia6:
        """Pinocchio order Ixx Ixy Iyy Ixz Iyz Izz."""
        i = self.inertia_com_kgm2
        return (i[0, 0], i[0, 1], i[1, 1], i[0, 2], i[1, 2], i[2, 2])


def flange_placement(robot: Robot) -> pin.SE3:
    """The flange frame in the last joint's frame (InputError if the flange is not on the last link)."""
    m = robot.model
    flange = m.frames[robot.flange_frame_id]
    if flange.parentJoint != m.njoints - 1:
        raise InputError(
            f"the flange {flange.name!r} (the TCP's parent frame) is not on the last link: a payload "
            "there is not part of the last link's inertia",
            field="tcp.parent_frame",
        )
    return flange.placement


def last_link_columns(robot: Robot) -> slice:
    """The last link's 10 columns in `rxcomm.model.dynamics.joint_torque_regressor` (link-major)."""
    return slice(10 * (robot.n - 1), 10 * robot.n)


def payload_inertial(robot: Robot, load: FlangeInertia) -> np.ndarray:
    """The load's 10 inertial parameters in the last joint's frame (Pinocchio order). Linear in the
    inertia about the centre of mass, so an identified one that is no body's within its σ (a light load's
    small moments, e.g. Ixx −0.0004 ± 0.0004 kg·m² at 0.5 kg) is taken as estimated: the point mass
    moved to the joint frame (Pinocchio's Inertia refuses a non-positive tensor) plus R·I_c·Rᵀ."""
    place = flange_placement(robot)
    point = pin.Inertia(float(load.mass_kg), np.asarray(load.com_m, float), np.zeros((3, 3)))
    out = place.act(point).toDynamicParameters()
    i_c = place.rotation @ np.asarray(load.inertia_com_kgm2, float) @ place.rotation.T
    out[4:] += [i_c[0, 0], i_c[0, 1], i_c[1, 1], i_c[0, 2], i_c[1, 2], i_c[2, 2]]
    return out


def flange_inertia(robot: Robot, inertial: np.ndarray) -> FlangeInertia:
    """10 parameters in the last joint's frame (e.g. identified) → mass, centre of mass and inertia
    about it in the flange frame. The mass must be positive (Pinocchio's storage)."""
    p = np.asarray(inertial, float)
    if not p[0] > 0:
        raise InputError(f"the payload's mass {p[0]:.4g} kg is not positive: no centre of mass")
    body = flange_placement(robot).actInv(pin.Inertia.FromDynamicParameters(p))
    return FlangeInertia(float(body.mass), np.array(body.lever), np.array(body.inertia))


def with_payload(robot: Robot, params: DynamicParameters, load: FlangeInertia | None) -> DynamicParameters:
    """`params` with the load added to the last link's inertials (unchanged for None)."""
    if load is None:
        return params
    inertial = np.array(params.inertial)
    inertial[-1] += payload_inertial(robot, load)
    return replace(params, inertial=inertial)


def load_payload(path: str | Path, robot: Robot) -> FlangeInertia:
    """Read an identified payload (`payload.yaml`, kind rxcomm/Payload) for `robot`'s flange (InputError
    naming the file and field when it is another robot's or has no positive mass)."""
    art = read_yaml_artefact(path, Payload)
    if art.robot != robot.name:
        raise InputError(
            f"the payload was identified on robot {art.robot!r}, not {robot.name!r}", file=path, field="robot"
        )
    flange = robot.model.frames[robot.flange_frame_id].name
    if art.flange_frame != flange:
        raise InputError(
            f"the payload is given in frame {art.flange_frame!r}, the robot's flange is {flange!r}",
            file=path,
            field="flange_frame",
        )
    return FlangeInertia(art.mass_kg, np.array(art.com_m, float), inertia_matrix(art.inertia_com_kgm2))


def model_parameters(
    robot: Robot, dynamics: str | Path | None, payload: str | Path | None
) -> tuple[DynamicParameters | None, Robot]:
    """The planners' and run's torque model: the identified `dynamics.yaml` (the prior without) with an
    identified `payload.yaml` on the last link (None when neither is given: the caller's prior), and
    the robot to evaluate it on: the nominal `robot` with the kinematics the model was fitted on."""
    from rxcomm.model.base_parameters import load_dynamics
    from rxcomm.model.dynamics import prior_parameters

    if dynamics is None and payload is None:
        return None, robot
    params, fitted = (prior_parameters(robot), robot) if dynamics is None else load_dynamics(dynamics, robot)
    if payload is not None:
        params = with_payload(fitted, params, load_payload(payload, fitted))
    return params, fitted


def model_inputs(dynamics: str | Path | None, payload: str | Path | None) -> dict[str, Path]:
    """The envelope inputs of a torque model: dynamics and payload files, those given."""
    return {k: Path(v) for k, v in (("dynamics", dynamics), ("payload", payload)) if v is not None}


def model_name(dynamics: str | Path | None, payload: str | Path | None) -> str:
    """What a plan's torques came from: "identified" or "prior", "+ payload" when one was added."""
    return ("identified" if dynamics is not None else "prior") + (" + payload" if payload is not None else "")
