"""Checks that a calibration describes this robot, and what the user should be told.

Before the fit: orientations that no rigid tool explains (angle convention). After it: positions
still far from the robot (wrong robot, joint order, units), a tool far from drives.yaml's TCP,
residuals far above a given noise, parameters the data cannot determine, and a calibration worse
than the nominal model on the held-out poses beyond their noise (`InfeasibleError`, exit 3; within
it, a note).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin
from scipy.stats import chi2

from rxcomm.calibration.diagnosis import heldout_standardised
from rxcomm.calibration.frames import DataFrames
from rxcomm.calibration.lm import FitResult, Fitter, at_links
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.residuals import ErrorStats, pose_errors
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.geometric_errors import characteristic_length_m, parameter_names
from rxcomm.model.robot import Robot

# The tool correction beyond which drives.yaml's TCP is called wrong on the console.
TOOL_WARNING_M, TOOL_WARNING_RAD = 0.005, 0.02
# A rigid tool leaves at most this rms orientation after the closed-form frames (else: angle convention).
RIGID_TOOL_RAD = 0.05
# After the fit, positions further than this (median) from the robot's mean the wrong robot or data.
FITTED_MEDIAN_LIMIT_M = 0.01


def check_rigid_tool(data: DataFrames, ms: MeasurementSet) -> None:
    """InputError when the best base and tool rotations leave the orientations far off."""
    if data.rotation_rms_rad is None or data.rotation_rms_rad <= RIGID_TOOL_RAD:
        return
    conv = f" (read as {ms.angle_convention})" if ms.angle_convention else ""
    raise InputError(
        f"the measured orientations{conv} do not fit a rigid tool: with the best base and tool "
        f"rotations they are still {np.degrees(data.rotation_rms_rad):.1f}° rms off. Check the angle "
        "convention: alpha/beta/gamma columns are Cardan x-y-z (R = Rx·Ry·Rz), roll/pitch/yaw "
        "columns R = Rz·Ry·Rx, or give quaternion columns qw, qx, qy, qz (docs/calibrate-csv.md)",
        file=ms.source,
        field="orientation",
    )


def check_fits_robot(
    robot: Robot, ms_fit: MeasurementSet, result: FitResult, tau: np.ndarray, t2b: pin.SE3, point
) -> None:
    """What base, tool and joint errors cannot explain is the wrong robot or data (InputError)."""
    e_fit, _ = pose_errors(robot, at_links(ms_fit, result, tau), result.errors, t2b, point)
    med = float(np.median(np.linalg.norm(e_fit, axis=1)))
    if med > FITTED_MEDIAN_LIMIT_M:
        raise InputError(
            f"after fitting base, tool and joint errors the measured positions are still {med * 1e3:.0f} mm "
            "(median) from the robot's: wrong robot, joint order or signs, units, or joint angles that do "
            "not belong to the positions",
            file=ms_fit.source,
            field="position_m",
        )


def fit_notes(result: FitResult, position_only: bool, noise_given: bool) -> list[str]:
    """Notes on the tool offset folded in, residuals above a given noise, position-only data."""
    notes = []
    tool = pin.exp6(result.errors.twist("tool"))
    rot = float(np.linalg.norm(pin.log3(tool.rotation)))
    if np.linalg.norm(tool.translation) > TOOL_WARNING_M or (not position_only and rot > TOOL_WARNING_RAD):
        notes.append(
            f"the tool (TCP) is {np.linalg.norm(tool.translation) * 1e3:.1f} mm"
            + ("" if position_only else f" / {np.degrees(rot):.2f}°")
            + " from drives.yaml's tcp: the calibration folds it in (update drives.yaml's tcp)"
        )
    if noise_given and result.residual_scale > 3:
        notes.append(
            f"residuals are {result.residual_scale:.1f}× the given tracker noise: the noise spec is "
            "optimistic or the model misses an effect"
        )
    if position_only:
        notes.append("position-only measurements: orientation is not measured, not scored, not calibrated")
    return notes


# A parameter whose posterior σ is above this share of its prior σ is mostly the prior's, not the data's.
PRIOR_SHARE_UNDETERMINED = 0.7

# The χ² quantile of the held-out poses' standardised misfit up to which a calibration no better
# than the nominal model is the noise's doing, not a robot the measurements fail to describe.
NOISE_QUANTILE = 0.999


def undetermined_parameters(
    robot: Robot,
    idx: tuple[int, ...],
    comp: tuple[int, ...],
    result: FitResult,
    limit_m: float,
    prior: np.ndarray | None = None,
) -> list[str]:
    """Parameters whose σ at the TCP (m; rotations × the characteristic length) exceeds `limit_m`,
    or (with a `prior` [48] σ) whose σ is still above PRIOR_SHARE_UNDETERMINED of their prior's (the data
    hardly inform them: the estimate stays near the prior), and compliances known to worse than 30 %."""
    names = parameter_names(robot)
    length = characteristic_length_m(robot)
    lever = np.tile(np.array([1, 1, 1, length, length, length]), robot.n + 2)
    prior = np.full(len(names), np.inf) if prior is None else prior
    out = [
        names[i]
        for i in idx
        if result.std[i] * lever[i] > limit_m or result.std[i] > PRIOR_SHARE_UNDETERMINED * prior[i]
    ]
    for j in comp:
        if not result.compliance_std[j] < 0.3 * abs(result.compliance[j]):
            out.append(f"{robot.joint_names[j]}.compliance")
    return out


def check_beats_nominal(
    fitter: Fitter,
    result: FitResult,
    fit: np.ndarray,
    heldout: np.ndarray,
    tables: dict[tuple[str, str], ErrorStats],
) -> str | None:
    """InfeasibleError (exit 3) when the calibration misses the held-out poses by more than the
    nominal model (in the fit's own weighted metric) *and* by more than the noise and its own
    uncertainty explain (Σ z² over their components beyond the χ² 99.9 % quantile). Within the noise
    it is a note: the nominal model is then already as good as these measurements can tell (a robot
    calibrated before, camera-grade noise), not a robot the measurements fail to describe."""
    if not heldout.size:
        return None
    rigid_nominal = replace(fitter, idx=np.array([], dtype=int), comp=())
    r_nominal = rigid_nominal.problem(heldout).residual(np.zeros(0)).reshape(heldout.size, -1)
    nominal_mis = float(np.mean(np.sum(r_nominal**2, axis=1)))
    cal_mis = float(np.mean(fitter.weighted_misfit(heldout, result)))
    if cal_mis < nominal_mis:
        return None
    nom, cal = tables[("heldout", "nominal")], tables[("heldout", "calibrated")]
    ori = ""
    if nom.max_orientation_error_rad is not None:
        ori = (
            f", max orientation {np.degrees(nom.max_orientation_error_rad):.3f}° → "
            f"{np.degrees(cal.max_orientation_error_rad):.3f}°"
        )
    rms = f"{nom.rms_position_error_m * 1e3:.3f} → {cal.rms_position_error_m * 1e3:.3f} mm"
    figures = f"rms position {rms}{ori}"
    _, z = heldout_standardised(fitter, result, fit, heldout)
    if float(np.sum(z**2)) <= chi2.ppf(NOISE_QUANTILE, z.size):
        return (
            f"the calibration does not beat the nominal model on the {heldout.size} held-out poses "
            f"({figures}), but misses them within the noise: the nominal model is already as good as "
            "these measurements can tell (calibrated before? more or better poses would show more)"
        )
    raise InfeasibleError(
        f"the calibration is worse than the nominal model on the {heldout.size} held-out poses "
        f"({figures}), beyond the noise: the measurements do not describe this robot as modelled "
        "(angle convention, joint order, a moving tracker?); nothing written"
    )
