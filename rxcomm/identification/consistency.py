"""Physical consistency of an identified parameter set (`rxcomm.identification.fit`).

**Physical consistency.** A base estimate is realisable by a physical robot if some full parameter
vector with K·p = p_b has every link's pseudo-inertia J = [[½tr(I)·1 − I, m·c], [(m·c)ᵀ, m]]
positive definite (Wensing et al. 2017) and non-negative rotor inertias, friction and spring. Always
reported: the minimum eigenvalue of each link's J for the full vector closest to the prior
(`parameters_from_base`), and the Mahalanobis distance √((p_b* − p̂)ᵀ·Λ·(p_b* − p̂)) (Λ the
information matrix WᵀΣ⁻¹W) from the unconstrained estimate p̂ to the nearest consistent p_b* —
in standard deviations: ≲ √p means "consistent within the noise". J is linear in the parameters, so
the consistent set is convex (a positive semi-definite cone per link, a half-line per drive
parameter) and `physical_fit` finds p_b* as a second-order-cone/semi-definite program (Clarabel,
an interior-point solver): its optimum, not a bound. With `physical=True` the body written is the
consistent one closest to the prior among those within √(d*² + 1) σ (`physical_fit`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import clarabel
import numpy as np
from scipy import sparse

from rxcomm.identification.estimation import Estimate
from rxcomm.model.base_parameters import (
    BaseParameterSet,
    parameter_scale,
    parameters_from_base,
)
from rxcomm.model.dynamics import (
    DynamicParameters,
    parameter_names,
    prior_parameters,
)
from rxcomm.model.robot import Robot


def pseudo_inertia(pi: np.ndarray) -> np.ndarray:
    """4 × 4 pseudo-inertia J = [[Σ, h], [hᵀ, m]] of the 10 parameters (m, h = m·c, Ixx Ixy Iyy Ixz Iyz
    Izz about the frame origin), Σ = ½tr(I)·1 − I. Positive definite ⇔ physically consistent."""
    m, h = pi[0], pi[1:4]
    i_o = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    j = np.empty((4, 4))
    j[:3, :3] = 0.5 * np.trace(i_o) * np.eye(3) - i_o
    j[:3, 3] = j[3, :3] = h
    j[3, 3] = m
    return j


def _from_pseudo_inertia(j: np.ndarray) -> np.ndarray:
    """Inverse of `pseudo_inertia` (linear): I = tr(Σ)·1 − Σ."""
    sigma = j[:3, :3]
    tr = sigma[0, 0] + sigma[1, 1] + sigma[2, 2]
    return np.array(
        [
            j[3, 3],
            j[0, 3],
            j[1, 3],
            j[2, 3],
            tr - sigma[0, 0],
            -sigma[0, 1],
            tr - sigma[1, 1],
            -sigma[0, 2],
            -sigma[1, 2],
            tr - sigma[2, 2],
        ]
    )


def _project_link(pi: np.ndarray, floor: float) -> np.ndarray:
    """The link's parameters with its pseudo-inertia's eigenvalues raised to `floor` (unchanged if all
    are above it)."""
    j = pseudo_inertia(pi)
    lam, vec = np.linalg.eigh(j)
    if lam[0] >= floor:
        return pi
    return _from_pseudo_inertia((vec * np.maximum(lam, floor)) @ vec.T)


# Clarabel's PSD cone holds a symmetric matrix as its upper triangle column by column, the entries
# off the diagonal × √2 (so that the vector's inner product is the matrices' trace inner product).
_SVEC_ENTRIES = [(r, c) for c in range(4) for r in range(c + 1)]


def _svec_matrix() -> np.ndarray:
    """[10, 10]: svec(pseudo_inertia(π)) = M·π (the pseudo-inertia is linear in π)."""
    m = np.empty((10, 10))
    for k in range(10):
        j = pseudo_inertia(np.eye(10)[k])
        m[:, k] = [j[r, c] * (1.0 if r == c else math.sqrt(2.0)) for r, c in _SVEC_ENTRIES]
    return m


_SVEC = _svec_matrix()
_SVEC_IDENTITY = np.array([1.0 if r == c else 0.0 for r, c in _SVEC_ENTRIES])


def link_min_eigenvalues(params: DynamicParameters) -> np.ndarray:
    """Per link, the smallest eigenvalue of its pseudo-inertia (kg·m²; > 0 ⇔ consistent)."""
    return np.array([np.linalg.eigvalsh(pseudo_inertia(pi))[0] for pi in params.inertial])


# Relative round-off of a least-squares solution (≈ 1e4 · machine ε): below it a value is zero.
ROUND_OFF = 1e-9
# An interior-point solver (as trf before it) keeps its iterates strictly inside the bounds, so a
# drive parameter the fit drives to its bound of 0 ends a little above it (trf: 1e-38 N·m·s/rad on
# the WidowX 250's viscous friction, 5e-10 N·m on the M1013's Coulomb): within this fraction of its
# typical magnitude it is at the bound, written as 0.
AT_BOUND = 1e-6


def drive_violations(params: DynamicParameters) -> list[str]:
    """Names of drive parameters that must not be negative but are (rotor inertia, Coulomb, viscous,
    spring k and k·L0); a value within round-off of zero (`ROUND_OFF` of the largest of its kind) is
    zero, not negative."""
    out = []

    def negative(v: np.ndarray | tuple, i: int) -> bool:
        v = np.asarray(v, dtype=float)
        return bool(v[i] < -ROUND_OFF * max(float(np.max(np.abs(v))), 1e-300))

    for i, j in enumerate(params.joint_names):
        for attr, name in (
            ("rotor_inertia_kgm2", "rotor_inertia"),
            ("coulomb_nm", "fc"),
            ("viscous_nm_s_per_rad", "fv"),
        ):
            if negative(getattr(params, attr), i):
                out.append(f"{j}.{name}")
    if params.spring is not None:
        out += [f"spring.{s}" for k, s in enumerate(("k", "kL0")) if params.spring[k] < 0]
    if params.has_motor_friction:
        for i, j in enumerate(params.joint_names):
            if negative(params.motor_coulomb_nm, i):
                out.append(f"{j}.fc_motor")
            if negative(params.motor_viscous_nm_s_per_rad, i):
                out.append(f"{j}.fv_motor")
    return out


@dataclass(frozen=True, eq=False)
class PhysicalFit:
    """The physically consistent estimates (module docstring): `mahalanobis` the distance
    √((p_b − p̂)ᵀΛ(p_b − p̂)) in standard deviations of the nearest one; `params` (full; `p_b` =
    K·params) the one written with `--physical`: of those within √(`mahalanobis`² + 1) σ, the
    closest to the prior, `params_mahalanobis` its distance; `success` (both solves converged),
    `message`."""

    params: DynamicParameters
    p_b: np.ndarray
    mahalanobis: float
    params_mahalanobis: float
    success: bool
    message: str


# Each link's pseudo-inertia is held this fraction of the prior's trace above singular, so that the
# body written stays positive definite through the solver's tolerance (1e-8 relative; kg and kg·m²
# mix in the trace: it is only a floor, 1e-9 of a 45 kg link's is 5e-8).
PSD_MARGIN = 1e-9
# The body written may fit the log this much worse (in χ², i.e. σ² summed) than the nearest
# consistent one: Δχ² = 1, one standard deviation along any direction. Measured against the whole
# noise ball (Δχ² = n_base) on the RX130L's and M900's multisine logs at 0.1–3 % noise: J1's
# validation error 0.28 against 0.37 N·m, J5's 0.0054 against 0.032 (the unconstrained estimate's
# 0.31 and 0.0082), where the ball put every mass at the prior's.
PRIOR_BUDGET_CHI2 = 1.0
_SOLVED = ("Solved", "AlmostSolved")
# Beyond ~700σ one σ more is below the solver's relative tolerance (a noise-free log: 6.4e6σ, and
# the second program failed numerically): there it may fit this fraction of the distance worse.
_RELATIVE_SLACK = 1e-6


def _minimise_norm(
    g: np.ndarray, h: np.ndarray, rows: np.ndarray, rhs: np.ndarray, cones: list
) -> tuple[np.ndarray, str]:
    """z minimising ‖G·z − h‖ subject to rhs − rows·z in `cones` (Clarabel: A·x + s = b, s ∈ K), as
    min t over x = [z, t] with [t, G·z − h] in a second-order cone; and the solver's status."""
    nz = g.shape[1]
    objective = np.zeros((1 + len(h), nz + 1))
    objective[0, nz] = -1.0
    objective[1:, :nz] = -g
    a = np.vstack([objective, np.hstack([rows, np.zeros((len(rows), 1))])])
    b = np.concatenate([np.zeros(1), -h, rhs])
    q = np.zeros(nz + 1)
    q[nz] = 1.0
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solution = clarabel.DefaultSolver(
        sparse.csc_matrix((nz + 1, nz + 1)),
        q,
        sparse.csc_matrix(a),
        b,
        [clarabel.SecondOrderConeT(1 + len(h)), *cones],
        settings,
    ).solve()
    return np.asarray(solution.x[:nz]), str(solution.status)


def physical_fit(
    robot: Robot,
    bset: BaseParameterSet,
    est: Estimate,
    prior: DynamicParameters | None = None,
) -> PhysicalFit:
    """The physically consistent parameters nearest to the estimate, and the body written (module
    docstring).

    If the full vector closest to the prior that reproduces p̂ (`parameters_from_base`) is consistent
    already, it is the answer (distance 0). Otherwise two convex problems over the full vector scaled
    by `parameter_scale`, with each link's pseudo-inertia ⪰ `PSD_MARGIN`·tr(prior's)·1 and the drive
    parameters ≥ 0: the least ‖R·(K·p − p̂)‖ (Λ = RᵀR), the nearest distance d; then the least
    ‖(p − p_prior)/scale‖ with ‖R·(K·p − p̂)‖² ≤ d² + `PRIOR_BUDGET_CHI2` (far away, ≤ d·(1 + 1e-6)).
    The first alone leaves the directions the data do not see anywhere (a 127 kg link 1 on a 3.7 kg
    UR5e at 4.1σ); the second takes the prior's there (3.7 kg) and moves what the data barely see
    towards it by at most one standard deviation. If the solver returns no point, the closest full
    vector is projected (`success` false, its own distance the figure). A drive parameter within
    `AT_BOUND` of its bound of 0 is 0."""
    prior = prior_parameters(robot) if prior is None else prior.conform(robot)
    n = robot.n
    names = parameter_names(robot.joint_names, prior.has_spring, prior.has_motor_friction)
    closest = parameters_from_base(robot, bset, est.p_b, prior)
    p_c = closest.vector()
    info = 0.5 * (est.info + est.info.T)
    if np.all(link_min_eigenvalues(closest) > 0) and not drive_violations(closest):
        p_b = bset.project(p_c)
        return PhysicalFit(closest, p_b, 0.0, 0.0, True, "the closest full vector is consistent")
    scale = parameter_scale(names, prior.vector(), n)
    nonneg = [10 * n + k * n + i for k in (0, 1, 2) for i in range(n)]  # rotor, fc, fv
    m0 = 14 * n + (2 if prior.has_spring else 0)
    if prior.has_spring:
        nonneg += [14 * n, 14 * n + 1]
    if prior.has_motor_friction:
        nonneg += list(range(m0, m0 + 2 * n))
    nz = len(p_c)
    margins = [PSD_MARGIN * float(np.trace(pseudo_inertia(pi))) for pi in prior.inertial]
    # consistency over z = p/scale: each link's svec(J − margin·1) and the drive parameters in their cones
    rows = np.zeros((10 * n + len(nonneg), nz))
    rhs = np.zeros(len(rows))
    for i in range(n):
        rows[10 * i : 10 * i + 10, 10 * i : 10 * i + 10] = -_SVEC * scale[10 * i : 10 * i + 10]
        rhs[10 * i : 10 * i + 10] = -margins[i] * _SVEC_IDENTITY
    rows[10 * n + np.arange(len(nonneg)), nonneg] = -scale[nonneg]
    cones = [clarabel.PSDTriangleConeT(4) for _ in range(n)] + [clarabel.NonnegativeConeT(len(nonneg))]

    # Λ = RᵀR exactly (a jitter on the diagonal before a Cholesky factor would outweigh the smallest
    # eigenvalues of Λ, the directions the data barely see, and tighten the bound there)
    lam, vec = np.linalg.eigh(info)
    r_info = np.sqrt(np.maximum(lam, 0.0))[:, None] * vec.T
    a_mat = r_info @ bset.K * scale
    b_vec = r_info @ est.p_b

    def distance(z: np.ndarray) -> float:
        return float(np.linalg.norm(a_mat @ z - b_vec))

    z, status = _minimise_norm(a_mat, b_vec, rows, rhs, cones)
    nearest, message, status2 = distance(z), f"nearest: {status}", "not run"
    if status in _SOLVED:
        allow = max(math.sqrt(nearest**2 + PRIOR_BUDGET_CHI2), (1.0 + _RELATIVE_SLACK) * nearest)
        data = np.vstack([np.zeros((1, nz)), -a_mat])  # [allow, A·z − b] in a second-order cone
        z2, status2 = _minimise_norm(
            np.eye(nz),
            prior.vector() / scale,
            np.vstack([data, rows]),
            np.concatenate([[allow], -b_vec, rhs]),
            [clarabel.SecondOrderConeT(1 + len(b_vec)), *cones],
        )
        message += f"; closest to the prior within {allow:.3g} σ: {status2}"
        if status2 in _SOLVED:
            z = z2
    if not np.all(np.isfinite(z)):  # a solver failure returns no point: take the closest full vector
        z = p_c / scale
    p = scale * z
    for i in range(n):  # through the solver's tolerance, strictly positive definite
        p[10 * i : 10 * i + 10] = _project_link(p[10 * i : 10 * i + 10], 0.5 * margins[i])
    p[nonneg] = np.where(p[nonneg] <= AT_BOUND * scale[nonneg], 0.0, p[nonneg])
    p_b = bset.K @ p
    d = p_b - est.p_b
    params = DynamicParameters.from_vector(robot.joint_names, p, prior.has_spring, prior.has_motor_friction)
    written = float(math.sqrt(max(d @ info @ d, 0.0)))
    if status not in _SOLVED:  # no optimum: the body's own distance, a bound
        nearest = written
    return PhysicalFit(params, p_b, nearest, written, status in _SOLVED and status2 in _SOLVED, message)
