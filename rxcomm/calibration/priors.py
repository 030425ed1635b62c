"""Priors on the geometric error parameters: what manufacturing tolerances say before any pose is
measured, so that the calibration is a regularised (maximum a posteriori) estimate.

Each error parameter p_k of a joint has a zero-mean Gaussian prior N(0, s_k²) with s_k from its
class (architecture §11 "Calibration priors" gives the sources). The fit estimates the identifiable
parameters p, which also carry the errors the structure folds into them, so their prior is N(0, Σ)
with Σ from the classes and the folds (`effective_priors`), and the fit minimises

    Σᵢ ‖rᵢ‖² + pᵀ·Σ⁻¹·p        (`Regularised`: the rows W·p, W = L⁻¹ for Σ = L·Lᵀ)

(the weighted residual rᵢ of `residuals`). With few noisy poses the data cannot outweigh the prior
and the estimate shrinks toward the base + tool frames alone (which are unconstrained: the cell sets
them up, the data find them in closed form); with many good poses the prior is negligible and the
estimate is the full model's. So the full model is never much worse than its own frames-only
baseline, and there is no discrete model switch to flip by noise.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from rxcomm.calibration.compliance import TAU_REF_NM
from rxcomm.calibration.residuals import Problem
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
    """[48] the prior σ of each identifiable parameter as the fit sees it (`effective_priors`)."""
    return effective_priors(robot, identifiable, q, position_only, point)[0]


def effective_priors(
    robot: Robot, identifiable: np.ndarray, q: np.ndarray, position_only: bool, point: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """([48] σ, [48, 48] correlation): the prior of the identifiable parameters as the fit sees it:
    each also carries the errors the structure folds into it (a non-identifiable parameter's
    Jacobian column is a combination Σ c_i·col_i of identifiable ones over the poses `q`), so their
    covariance is diag(σ_i²) + Σ_j c_ij·c_i'j·σ_j² over the non-identifiable parameters j, and
    σ_eff,i² its diagonal. A prior on the identifiable parameters alone would be too tight: it made
    a linear scan's calibration 2× worse at tracker grade. The correlation matters where one error
    folds into several parameters: on MuJoCo Menagerie's i2rt YAM (parallel J2, J3) into joint_3.rz
    and joint_4.rz with σ_eff 17 and 30 mrad, and a diagonal prior held their common direction back
    as if each moved alone (20 camera-grade campaigns against the truth: 2.26 mm, with the
    correlation 1.63, the plain fit 1.49). A frame component j folded into i (σ_j = ∞: on a 6R arm
    the tool's tz and rz are joint_6's tz and rz) makes i flat: the frames-only fit moves the tool
    along and about its axis freely, so the full fit must too, or its prior pulls a tool length that
    drives.yaml gets wrong back to nominal (at camera grade a 10 mm longer tool was 20 % worse than
    frames-only on held-out poses, a 20 mm one 3.8× or refused as the wrong robot). Other entries as
    `parameter_prior_sigmas`; the correlation is the identity outside the finite block."""
    sig = parameter_prior_sigmas(robot)
    corr = np.eye(sig.size)
    ident = np.asarray(identifiable, dtype=int)
    rest = np.setdiff1d(np.arange(sig.size), ident)
    if rest.size == 0:
        return sig, corr
    jac = identification_jacobians(robot, q, None, None, position_only, point).reshape(-1, sig.size)
    c, *_ = np.linalg.lstsq(jac[:, ident], jac[:, rest], rcond=None)
    # c_ij·|col_i| / |col_j|: the share of column j that i carries (dimensionless; 0 for a zero column)
    norms = np.linalg.norm(jac, axis=0)
    share = np.abs(c) * norms[ident, None] / np.maximum(norms[rest], 1e-300)
    flat = ~np.isfinite(sig[rest])
    out = sig.copy()
    finite = np.isfinite(out[ident])
    ci = c[finite][:, ~flat]
    cov = np.diag(sig[ident[finite]] ** 2) + (ci * sig[rest[~flat]] ** 2) @ ci.T
    out[ident[finite]] = np.sqrt(np.diag(cov))
    corr[np.ix_(ident[finite], ident[finite])] = cov / np.outer(out[ident[finite]], out[ident[finite]])
    out[ident[np.any(share[:, flat] > 1e-6, axis=1)]] = np.inf
    return out, corr


def prior_sigmas(
    robot: Robot, idx: np.ndarray, comp: tuple[int, ...], geometric: np.ndarray | None = None
) -> np.ndarray:
    """Prior σ of a fit's solution vector: the geometric parameters `idx` (σ from `geometric` [48],
    default `parameter_prior_sigmas`), then the compliant joints' c·TAU_REF (`residuals.Problem`);
    inf where the prior is flat."""
    geo = (parameter_prior_sigmas(robot) if geometric is None else geometric)[np.asarray(idx, dtype=int)]
    return np.concatenate([geo, np.full(len(comp), COMPLIANCE_SIGMA_RAD_PER_NM * TAU_REF_NM)])


@dataclass(frozen=True)
class Regularised:
    """A weighted residual with its prior rows W·x_R appended (R the elements with a finite σ,
    `priors`): W = L⁻¹ for the prior covariance L·Lᵀ = diag(σ_R)·`corr`_RR·diag(σ_R), so the rows
    are x_k/σ_k where `corr` is None (uncorrelated), and they weigh a direction the structure folds
    several errors into (`priors.effective_priors`) by its own variance, not each element's."""

    prob: Problem
    prior: np.ndarray | None
    corr: np.ndarray | None = None  # [k, k] the prior's correlation over the solution vector

    @property
    def rows(self) -> np.ndarray:
        return np.zeros(0, dtype=int) if self.prior is None else np.flatnonzero(np.isfinite(self.prior))

    @cached_property
    def whitening(self) -> np.ndarray:
        """W [|R|, |R|] (lower triangular)."""
        rows = self.rows
        sigma = self.prior[rows]
        if self.corr is None:
            return np.diag(1.0 / sigma)
        cov = self.corr[np.ix_(rows, rows)] * np.outer(sigma, sigma)
        return np.linalg.inv(np.linalg.cholesky(cov))

    @property
    def information(self) -> np.ndarray:
        """[k, k] the prior's information WᵀW (0 where flat)."""
        k = len(self.prob.idx) + len(self.prob.comp)
        out = np.zeros((k, k))
        if self.prior is not None:
            rows, w = self.rows, self.whitening
            out[np.ix_(rows, rows)] = w.T @ w
        return out

    @property
    def n_free(self) -> int:
        return len(self.prob.idx) + len(self.prob.comp) - self.rows.size

    def residual(self, x: np.ndarray) -> np.ndarray:
        if self.prior is None:
            return self.prob.residual(x)
        return np.concatenate([self.prob.residual(x), self.whitening @ x[self.rows]])

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        if self.prior is None:
            return self.prob.jacobian(x)
        rows = self.rows
        extra = np.zeros((rows.size, x.size))
        extra[:, rows] = self.whitening
        return np.vstack([self.prob.jacobian(x), extra])
