"""Priors on the geometric error parameters: what manufacturing tolerances say before any pose is
measured, so that the calibration is a regularised (maximum a posteriori) estimate.

Each error parameter p_k of a joint has a zero-mean Gaussian prior N(0, s_k²) with s_k from its
class (architecture §11 "Calibration priors" gives the sources); the fit minimises

    Σᵢ ‖rᵢ‖² + Σ_k (p_k / s_k)²

(the weighted residual rᵢ of `residuals`). With few noisy poses the data cannot outweigh the prior
and the estimate shrinks toward the base + tool frames alone (which are unconstrained: the cell sets
them up, the data find them in closed form); with many good poses the prior is negligible and the
estimate is the full model's. So the full model is never much worse than its own frames-only
baseline, and there is no discrete model switch to flip by noise.
"""

from __future__ import annotations

import numpy as np

from rxcomm.calibration.compliance import TAU_REF_NM
from rxcomm.model.geometric_errors import joint_offset_names, parameter_names
from rxcomm.model.robot import Robot

# 1σ per class (SI). Sources and rationale: docs/architecture.md §11 "Calibration priors".
LINK_LENGTH_SIGMA_M = 1.0e-3  # a joint's translation errors (link lengths and offsets)
AXIS_TILT_SIGMA_RAD = 1.0e-3  # a joint's two rotations across its axis (misalignment)
JOINT_OFFSET_SIGMA_RAD = 2.0e-3  # the rotation about its own axis (encoder zero)
COMPLIANCE_SIGMA_RAD_PER_NM = 1.0e-5  # joint compliance c = 1/k (stiffness ≥ 1e5 N·m/rad)


def parameter_prior_sigmas(robot: Robot) -> np.ndarray:
    """[48] prior σ per error parameter (`parameter_names` order); inf for the base and tool frames."""
    names = parameter_names(robot)
    offsets = set(joint_offset_names(robot))
    out = np.full(len(names), np.inf)
    for i, name in enumerate(names):
        group, comp = name.split(".")
        if group in ("base", "tool"):
            continue
        if name in offsets:
            out[i] = JOINT_OFFSET_SIGMA_RAD
        elif comp.startswith("t"):
            out[i] = LINK_LENGTH_SIGMA_M
        else:
            out[i] = AXIS_TILT_SIGMA_RAD
    return out


def prior_sigmas(robot: Robot, idx: np.ndarray, comp: tuple[int, ...]) -> np.ndarray:
    """Prior σ of a fit's solution vector: the geometric parameters `idx`, then the compliant
    joints' c·TAU_REF (`residuals.Problem`); inf where the prior is flat."""
    geo = parameter_prior_sigmas(robot)[np.asarray(idx, dtype=int)]
    return np.concatenate([geo, np.full(len(comp), COMPLIANCE_SIGMA_RAD_PER_NM * TAU_REF_NM)])
