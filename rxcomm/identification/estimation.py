"""Base parameters by least squares, with their statistics (`rxcomm.identification.fit`).

**Estimation** (`estimate`). τ = Y(q, q̇, q̈)·p with `rxcomm.model.dynamics.joint_torque_regressor` (links,
rotor inertia, Coulomb (exact sign), viscous, offset, spring, and with drives.yaml `friction: motor|both`
the motors' Coulomb and viscous friction through Rᵀ), reduced to the base parameters
(`BaseParameterSet`, the paper's κ regrouping, recorded in dynamics.yaml). Rows of joint j where
|q̇_j| < `min_speed_rad_s` are rejected: there the Coulomb term's sign is uncertain and the real
friction (stiction) is not Fc·sgn(q̇). So are the rows within `stick_guard_s` (default 1/cutoff) of
such a sample at the source rate: the low-pass spreads the stick phase's friction (anything within
±Fc) over that time, which parallel filtering of sgn(q̇) cannot reproduce; near reversals the
residual is 2–6× the noise, beyond 1/cutoff at the noise. A coupled motor with friction sticks when
its own velocity R_i·q̇ passes zero, so its slow samples guard every joint it loads: without that
guard a simulated motor-6 stiction of 0.027 N·m came out 4σ low on the cell, with it 0.2σ.
Ordinary least squares, then weighted least squares with each joint's rows divided by its noise
standard deviation σ_j² = ‖r_j‖²/(m_j − p)
from the OLS residuals (Gautier's WLS); covariance (WᵀΣ⁻¹W)⁻¹ and relative standard deviations
σ_p/|p|. Normal equations on unit-norm columns (cond ≲ 10³ here) keep every decomposition p × p. A
regressor whose unit-column condition number exceeds `max_cond` is refused, naming the base
parameters the log does not excite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from rxcomm.errors import InputError
from rxcomm.identification.processing import Processed, regressor
from rxcomm.identification.settings import IdentifySettings
from rxcomm.model.base_parameters import BaseParameterSet
from rxcomm.model.robot import Robot


@dataclass(frozen=True, eq=False)
class Estimate:
    """A base-parameter estimate: `p_b`, covariance `cov`, `relative_std` (σ/|p|), per-joint noise
    `sigma_joint_nm` (from the residuals of the method's weighting), `info` = WᵀΣ⁻¹W, the unit-column
    condition numbers, rows used/rejected, fit residual RMS per joint."""

    p_b: np.ndarray
    cov: np.ndarray
    relative_std: np.ndarray
    sigma_joint_nm: np.ndarray
    info: np.ndarray
    cond: float
    cond_raw: float
    n_rows: int
    n_rejected: int
    residual_rms_nm: np.ndarray
    p_ols: np.ndarray


def _solve_normal(w: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(p, (WᵀW)⁻¹, WᵀW) by normal equations on unit-norm columns."""
    norms = np.linalg.norm(w, axis=0)
    wn = w / norms
    g = wn.T @ wn
    c = sla.cho_factor(g)
    p = sla.cho_solve(c, wn.T @ y) / norms
    g_inv = sla.cho_solve(c, np.eye(len(g))) / np.outer(norms, norms)
    return p, g_inv, (w.T @ w)


def excitation_report(
    w: np.ndarray, names: tuple[str, ...], max_cond: float
) -> tuple[float, float, list[str]]:
    """(cond, cond_raw, base parameters the data do not excite): those with the largest weights in
    the singular directions of the unit-column regressor whose singular value is below σ_max/max_cond."""
    norms = np.linalg.norm(w, axis=0)
    dead = [names[i] for i in np.flatnonzero(norms <= 1e-12 * max(norms.max(), 1e-300))]
    safe = np.where(norms > 0, norms, 1.0)
    wn = w / safe
    lam, vec = sla.eigh(wn.T @ wn)
    lam = np.maximum(lam, 0.0)
    cond = math.sqrt(lam[-1] / lam[0]) if lam[0] > 0 else math.inf
    if dead or not math.isfinite(cond):
        cond_raw = math.inf
    else:
        r = np.linalg.cholesky(wn.T @ wn).T
        s = np.linalg.svd(r * norms[None, :], compute_uv=False)
        cond_raw = float(s[0] / s[-1])
    weak = list(dead)
    for k in np.flatnonzero(lam < lam[-1] / max_cond**2):
        v = np.abs(vec[:, k])
        for i in np.flatnonzero(v >= 0.5 * v.max()):
            if names[i] not in weak:
                weak.append(names[i])
    return cond, cond_raw, weak


def estimate(
    robot: Robot,
    bset: BaseParameterSet,
    data: Processed,
    settings: IdentifySettings,
    *,
    source: str | None = None,
    w: np.ndarray | None = None,
) -> Estimate:
    """OLS, then (method "wls") WLS on the processed samples; refuses poor excitation. `w`: the base
    regressor of `data` [M·n, n_base] (rows sample-major) when the caller has it already."""
    n, nb = robot.n, bset.n_base
    w = bset.base_regressor(regressor(robot, data)) if w is None else w
    y = data.tau.ravel()
    joint = np.tile(np.arange(n), len(data.t))
    keep = ~data.near_stick.ravel()
    w, y, joint = w[keep], y[keep], joint[keep]
    cond, cond_raw, weak = excitation_report(w, bset.names, settings.max_cond)
    if cond > settings.max_cond or len(y) <= nb:
        still = [robot.joint_names[j] for j in range(n) if not np.any(joint == j)]
        parts = []
        if still:
            parts.append(
                f"{', '.join(still)} never moved faster than min_speed_rad_s = {settings.min_speed_rad_s} "
                "for longer than the stick guard (default 1/cutoff_hz)"
            )
        shown = [b for b in weak if b.split(".")[0] not in still]
        if shown:
            more = f" and {len(shown) - 12} more" if len(shown) > 12 else ""
            parts.append("not identifiable from this log: " + ", ".join(shown[:12]) + more)
        raise InputError(
            f"poor excitation: cond(W) = {cond:.3g} (unit-norm columns; limit max_cond = "
            f"{settings.max_cond:.3g}) over {len(y)} rows; {'; '.join(parts) or 'too few rows'}. "
            "Record an excitation trajectory (rxcomm excite) instead",
            file=source,
            field="q",
        )
    p_ols, g_inv, _ = _solve_normal(w, y)
    r = y - w @ p_ols
    m_j = np.bincount(joint, minlength=n)
    ss_j = np.bincount(joint, weights=r * r, minlength=n)
    dof = np.maximum(m_j - nb, 1)
    sigma = np.sqrt(ss_j / dof)
    if settings.method == "ols":
        s2 = float(r @ r) / max(len(y) - nb, 1)
        p, cov = p_ols, s2 * g_inv
        info = (w.T @ w) / s2
        sig = np.full(n, math.sqrt(s2))
    else:
        sig = np.maximum(sigma, 1e-9 * max(sigma.max(), 1e-12))
        wt = 1.0 / sig[joint]
        p, cov, info = _solve_normal(w * wt[:, None], y * wt)
        r = y - w @ p
    rms = np.sqrt(np.bincount(joint, weights=r * r, minlength=n) / np.maximum(m_j, 1))
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(p) > 0, std / np.abs(p), np.inf)
    return Estimate(
        p_b=p,
        cov=cov,
        relative_std=rel,
        sigma_joint_nm=sig,
        info=info,
        cond=cond,
        cond_raw=cond_raw,
        n_rows=int(len(y)),
        n_rejected=int((~keep).sum()),
        residual_rms_nm=rms,
        p_ols=p_ols,
    )


# ------------------------------------------------------------------------------------------------
# The same estimate from Gram matrices (cross-validation: one pass over the rows for every fold)


@dataclass(frozen=True, eq=False)
class JointGrams:
    """Sufficient statistics of some regressor rows, per joint j: `g` [n, nb, nb] = W_jᵀW_j, `b` [n, nb]
    = W_jᵀy_j, `c` [n] = y_jᵀy_j, `m` [n] rows. Sums of disjoint row sets add."""

    g: np.ndarray
    b: np.ndarray
    c: np.ndarray
    m: np.ndarray

    @classmethod
    def of_rows(cls, w: np.ndarray, y: np.ndarray, joint: np.ndarray, n: int) -> JointGrams:
        nb = w.shape[1]
        g, b = np.zeros((n, nb, nb)), np.zeros((n, nb))
        for j in range(n):
            k = joint == j
            wj = w[k]
            g[j], b[j] = wj.T @ wj, wj.T @ y[k]
        return cls(g, b, np.bincount(joint, weights=y * y, minlength=n), np.bincount(joint, minlength=n))

    @classmethod
    def total(cls, parts: list[JointGrams]) -> JointGrams:
        return cls(*(np.sum([getattr(p, f) for p in parts], axis=0) for f in ("g", "b", "c", "m")))


def _solve_gram(g: np.ndarray, b: np.ndarray, max_cond: float) -> np.ndarray | None:
    """p from the normal equations g·p = b on unit-norm columns; None if cond (unit columns) > max_cond."""
    norms = np.sqrt(np.maximum(np.diag(g), 0.0))
    if np.any(norms <= 0):
        return None
    gn = g / np.outer(norms, norms)
    lam = sla.eigvalsh(gn)
    if lam[0] <= 0 or math.sqrt(lam[-1] / lam[0]) > max_cond:
        return None
    return sla.solve(gn, b / norms, assume_a="pos") / norms


def estimate_from_grams(grams: JointGrams, settings: IdentifySettings) -> np.ndarray | None:
    """`estimate`'s base parameters (OLS, then per-joint WLS with σ_j² = ‖r_j‖²/(m_j − p)) from the
    rows' Gram matrices; None where `estimate` refuses the rows (poor excitation, too few rows)."""
    nb = grams.b.shape[1]
    if grams.m.sum() <= nb:
        return None
    p = _solve_gram(grams.g.sum(axis=0), grams.b.sum(axis=0), settings.max_cond)
    if p is None or settings.method == "ols":
        return p
    ss = grams.c - 2.0 * grams.b @ p + np.einsum("i,jik,k->j", p, grams.g, p)
    sigma = np.sqrt(np.maximum(ss, 0.0) / np.maximum(grams.m - nb, 1))
    sig2 = np.maximum(sigma, 1e-9 * max(sigma.max(), 1e-12)) ** 2
    return _solve_gram(
        np.tensordot(1.0 / sig2, grams.g, axes=1), (grams.b / sig2[:, None]).sum(axis=0), settings.max_cond
    )
