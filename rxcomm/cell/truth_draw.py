"""A plausible hidden truth for any robot (`rxcomm truth`): what the simulated cell will be.

Drawn from one seed around the robot's nominal description (URDF inertials, drives.yaml priors), at
the sizes of the samples' truths (architecture §6):

- geometry: every one of the 48 error parameters N(0, `SIGMA_LENGTH_M`) for translations and
  N(0, `SIGMA_ANGLE_RAD`) for rotations; the tracker where the cell file beside the robot puts it,
  else 2 × the reach in front of the base (−x);
- optional compliance: joints 2 and 3 with a stiffness that sags them `COMPLIANCE_SAG_RAD` under the
  largest holding torque of 200 random poses;
- dynamics: mass ×(1 + N(0, 5 %)), centre of mass + N(0, 5 mm), the inertia about it ×(1 + N(0, 5 %))
  (stays a physical body), rotor inertia ×(1 + N(0, 5 %)), friction ×(1 + N(0, 15 %)) (≥ 0), offsets
  N(0, 1 % of the drive's torque), the balancer (if any) k and L0 ×(1 + N(0, 5 %));
- noise: encoder 1 µrad, torque 0.4 % of the drive's torque, tracker 50 µm / 0.1 mrad, 3.5 ms latency.

The drive's torque (`drive_torque_nm`) is the peak torque, but at most `DRIVE_OF_NEED` × the largest
torque the joint needs within its limits: a simulation model's force clamp (MuJoCo Menagerie's ARX L5:
100 N·m on every joint, 0.36 N·m needed at its wrist) is no drive, and 1 % of it, a constant torque
0.86 N·m on a 0.005 kg·m² wrist against 0.3 N·m of friction, tripped 0x8611 32 ms after the brakes
released, before any motion (architecture §6.1).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from rxcomm.model.dynamics import RobotDynamics, prior_parameters, random_states
from rxcomm.model.geometric_errors import parameter_names
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import Cell
from rxcomm.schemas.truth import CellTruth

SIGMA_LENGTH_M = 1e-3
SIGMA_ANGLE_RAD = 1e-3
COMPLIANCE_SAG_RAD = 2e-4
MASS_REL, COM_M, INERTIA_REL, ROTOR_REL, FRICTION_REL = 0.05, 0.005, 0.05, 0.05, 0.15
OFFSET_OF_DRIVE, TORQUE_NOISE_OF_DRIVE = 0.01, 0.004
DRIVE_OF_NEED = 5.0  # the samples' peaks are 0.8–4.4 × their joints' largest need (M900 J6: 4.4)


def _link(pi: np.ndarray, rng: np.random.Generator) -> dict:
    m, mc = float(pi[0]), np.asarray(pi[1:4])
    xx, xy, yy, xz, yz, zz = pi[4:10]
    c = mc / m
    i_c = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]) - m * (c @ c * np.eye(3) - np.outer(c, c))
    m2 = m * (1 + MASS_REL * rng.standard_normal())
    c2 = c + COM_M * rng.standard_normal(3)
    i2 = i_c * (1 + INERTIA_REL * rng.standard_normal()) + m2 * (c2 @ c2 * np.eye(3) - np.outer(c2, c2))
    return {
        "mass_kg": round(float(m2), 6),
        "first_moment_kgm": [round(float(v), 7) for v in m2 * c2],
        "inertia_origin_kgm2": [
            round(float(i2[a, b]), 8) for a, b in ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))
        ],
    }


def drive_torque_nm(robot: Robot, n_states: int = 400) -> np.ndarray:
    """[n] the torque a drive of the simulated cell is sized for, N·m: the peak torque, at most
    `DRIVE_OF_NEED` × the largest |τ| of the prior model over random states within the position,
    velocity and acceleration limits (a fixed draw: a property of the robot, not of the seed)."""
    q, qd, qdd = random_states(robot, n_states, seed=0)
    need = np.abs(RobotDynamics(robot, prior_parameters(robot)).inverse_dynamics(q, qd, qdd)).max(axis=0)
    return np.minimum(np.asarray(robot.tau_max, float), DRIVE_OF_NEED * need)


def draw_truth(
    robot: Robot, truth_path: Path, seed: int, *, compliance: bool, cell: Cell | None
) -> CellTruth:
    """The truth for `robot`, to be written at `truth_path` (its `robot:` is relative to it)."""
    rng = np.random.default_rng(seed)
    names = parameter_names(robot)
    sigma = [SIGMA_ANGLE_RAD if n.split(".")[1].startswith("r") else SIGMA_LENGTH_M for n in names]
    errors = {n: round(float(s * rng.standard_normal()), 7) for n, s in zip(names, sigma, strict=True)}
    if cell is not None:
        t2b = cell.tracker.tracker_to_base.model_dump()
    else:
        t2b = {"xyz_m": (-2.0 * robot.reach_from_base_m, 0.0, 0.0), "rpy_rad": (0.0, 0.0, 0.0)}
    prior = prior_parameters(robot)
    stiffness = {}
    if compliance:
        q, _, _ = random_states(robot, 200, seed=seed)
        held = np.abs(RobotDynamics(robot, prior).gravity_torque(q)).max(axis=0)
        stiffness = {robot.joint_names[j]: float(f"{held[j] / COMPLIANCE_SAG_RAD:.3g}") for j in (1, 2)}
    n, drive = robot.n, drive_torque_nm(robot)

    def scale(v, rel: float) -> list[float]:
        return [round(float(x), 9) for x in np.maximum(np.asarray(v) * (1 + rel * rng.standard_normal(n)), 0)]

    dynamics = {
        "links": [
            {"link": j, **_link(pi, rng)} for j, pi in zip(robot.joint_names, prior.inertial, strict=True)
        ],
        "rotor_inertia_kgm2": scale(robot.rotor_inertia, ROTOR_REL),
        "coulomb_friction_nm": scale(robot.coulomb_prior, FRICTION_REL),
        "viscous_friction_nm_s_per_rad": scale(robot.viscous_prior, FRICTION_REL),
        "torque_offset_nm": [round(float(v), 4) for v in OFFSET_OF_DRIVE * drive * rng.standard_normal(n)],
    }
    if robot.drives.spring is not None:
        s = robot.drives.spring
        dynamics["spring_stiffness_n_per_m"] = round(
            s.stiffness_n_per_m * (1 + 0.05 * rng.standard_normal()), 3
        )
        dynamics["spring_free_length_m"] = round(s.free_length_m * (1 + 0.05 * rng.standard_normal()), 6)
    return CellTruth.model_validate(
        {
            "kind": "rxcomm/CellTruth",
            "schema_version": 1,
            "robot": os.path.relpath(robot.drives_path.parent.resolve(), truth_path.parent.resolve()),
            "seed": seed,
            "geometry": {
                "tracker_to_base": t2b,
                "error_parameters": errors,
                "joint_stiffness_nm_per_rad": stiffness,
            },
            "dynamics": dynamics,
            "noise": {
                "encoder_lsb_rad": 1e-6,
                "torque_noise_nm": [round(float(v), 4) for v in TORQUE_NOISE_OF_DRIVE * drive],
                "tracker_position_sigma_m": 5e-5,
                "tracker_orientation_sigma_rad": 1e-4,
                "tracker_latency_s": 0.0035,
            },
        }
    )
