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
from rxcomm.model.geometric_errors import identification_jacobians, joint_offset_names, parameter_names
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


def effective_prior_sigmas(
    robot: Robot, identifiable: np.ndarray, q: np.ndarray, position_only: bool, point: np.ndarray | None
) -> np.ndarray:
    """[48] the prior σ of each identifiable parameter as the fit sees it: it also carries the
    errors the structure folds into it (a non-identifiable parameter's Jacobian column is a
    combination Σ c_i·col_i of identifiable ones over the poses `q`), so
    σ_eff,i² = σ_i² + Σ_j c_ij²·σ_j² over the non-identifiable parameters j (correlations
    neglected). A prior on the identifiable parameters alone would be too tight: it made a linear
    scan's calibration 2× worse at tracker grade. A frame component j folded into i (σ_j = ∞: on
    a 6R arm the tool's tz and rz are joint_6's tz and rz) makes i flat: the frames-only fit moves
    the tool along and about its axis freely, so the full fit must too, or its prior pulls a tool
    length that drives.yaml gets wrong back to nominal (at camera grade a 10 mm longer tool was 20 %
    worse than frames-only on held-out poses, a 20 mm one 3.8× or refused as the wrong robot).
    Other entries as `parameter_prior_sigmas`."""
    sig = parameter_prior_sigmas(robot)
    ident = np.asarray(identifiable, dtype=int)
    rest = np.setdiff1d(np.arange(sig.size), ident)
    if rest.size == 0:
        return sig
    jac = identification_jacobians(robot, q, None, None, position_only, point).reshape(-1, sig.size)
    c, *_ = np.linalg.lstsq(jac[:, ident], jac[:, rest], rcond=None)
    # c_ij·|col_i| / |col_j|: the share of column j that i carries (dimensionless; 0 for a zero column)
    norms = np.linalg.norm(jac, axis=0)
    share = np.abs(c) * norms[ident, None] / np.maximum(norms[rest], 1e-300)
    flat = ~np.isfinite(sig[rest])
    out = sig.copy()
    finite = np.isfinite(out[ident])
    folded = (c[finite][:, ~flat] ** 2) @ (sig[rest[~flat]] ** 2)
    out[ident[finite]] = np.sqrt(sig[ident[finite]] ** 2 + folded)
    out[ident[np.any(share[:, flat] > 1e-6, axis=1)]] = np.inf
    return out


def prior_sigmas(
    robot: Robot, idx: np.ndarray, comp: tuple[int, ...], geometric: np.ndarray | None = None
) -> np.ndarray:
    """Prior σ of a fit's solution vector: the geometric parameters `idx` (σ from `geometric` [48],
    default `parameter_prior_sigmas`), then the compliant joints' c·TAU_REF (`residuals.Problem`);
    inf where the prior is flat."""
    geo = (parameter_prior_sigmas(robot) if geometric is None else geometric)[np.asarray(idx, dtype=int)]
    return np.concatenate([geo, np.full(len(comp), COMPLIANCE_SIGMA_RAD_PER_NM * TAU_REF_NM)])
