"""Base (identifiable) dynamic parameters by numerical QR (paper §4.1, architecture §7 identify).

The stacked regressor W of random states within the joint limits has rank r < P: some columns are
zero (parameters without effect) and some are linear combinations of others. We find

- the rank r from a pivoted QR of W with unit-norm columns (the gap between the kept and dropped
  |R_ii| is ~14 orders of magnitude on the sample robots: 0.3 against 1e-15). The tolerance is 1e-3,
  not a rounding floor: a model whose frames carry rounded angles (MuJoCo Menagerie's M1013: 1.571
  for π/2, a 0.2 mrad tilt) separates joint_2's Izz from its rotor inertia at |R_ii| = 2.7e-4 only,
  a direction no excitation conditions within identify's max_cond (its best trajectory: cond 1.28e4,
  refused at 1.74e4), so such a direction regroups as the exact model's would (the torque it leaves
  out is that fraction of a column's);
- which r columns to keep by an unpivoted QR in a preference order (links 1→6, within a link the
  rotational inertias before the first moments before the mass, then rotor inertias, friction, offset
  and spring): a column is kept when it is independent of all columns before it, so the base set keeps
  proximal inertial parameters and physically meaningful drive parameters wherever possible (the
  paper's Θ1/Θ2 split, eq. 21, with a readable choice of Θ1). Both QRs must agree on r;
- the regrouping K (r × P) with p_b = K·p: K[:, kept] = I and K[:, dropped] = κ = lstsq(W_1, W_2)
  (the paper's κ = R11⁻¹R12, eq. 25). Then W·p = W_1·p_b exactly for every state. A column dropped
  by the tolerance but not exactly dependent (relative residual above `EXACT_DEPENDENCE`: the rounded
  angles above, or a calibrated tilt, `identification.kinematics.base_set_on`) has no exact
  combination; the least squares over random states then spreads it thinly over every kept column
  (MuJoCo Menagerie's WidowX 250 on its calibrated axes: the shoulder's rotor inertia over all 60,
  its viscous friction "waist.fv − 1.46·shoulder.rotor_inertia"), so it is regrouped on the fewest
  columns that come within `SPARSE_SLACK` of that least squares' residual (`regrouping`): there, on
  the shoulder's Iyy and Iyz (residual 6.2e-4 of the column against 6.0e-4 on all 60).

A particular full vector for given base values (`parameters_from_base`) is the prior corrected by
the minimum *relative* change: p = p0 + S·(K·S)⁺·(p_b − K·p0), S = diag(typical magnitude of each
parameter). Any p with K·p = p_b gives the same τ(q, q̇, q̈); the scaled minimum-norm choice keeps the
non-identifiable parts (and the masses) near their CAD values instead of moving whichever parameter
has the largest coefficient, which keeps Pinocchio's (m, c, I_c) storage well defined.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.model.dynamics import (
    INERTIAL_PARAMETERS,
    DynamicParameters,
    joint_torque_regressor,
    parameter_names,
    prior_parameters,
    random_states,
)
from rxcomm.model.robot import Robot
from rxcomm.schemas.dynamics import Dynamics

RANK_TOLERANCE = 1e-3  # on |R_ii| / |R_00| of the unit-column regressor (module docstring)
_ZERO_COLUMN = 1e-10  # a column whose norm is below this fraction of the largest has no effect
_COEFF_CLEAN = 1e-10  # regrouping coefficients whose relative contribution is below this are zero
# Relative residual of an exact dependency: measured ≤ 3.3e-10 (the geometry's regroupings on calibrated
# axes), against ≥ 2e-4 where a tilt or a rounded angle separates a column (module docstring).
EXACT_DEPENDENCE = 1e-8
SPARSE_SLACK = 0.1  # an inexact column's regrouping stops within 10 % of the full least squares' residual

# Floors of the typical magnitude of drive parameters whose prior may be zero (SI units).
_SCALE_FLOOR = {
    "rotor_inertia": 1e-6,
    "fc": 0.1,
    "fv": 0.1,
    "offset": 1.0,
    "k": 100.0,
    "kL0": 10.0,
    "fc_motor": 1e-5,  # motor side; small: a regrouped value stays on the joint side
    "fv_motor": 1e-7,
}


def _kind(name: str) -> str:
    suffix = name.rsplit(".", 1)[1]
    if suffix.startswith("mc"):
        return "mc"
    if suffix.startswith("I"):
        return "I"
    return suffix


def _preference_order(names: tuple[str, ...], n_joints: int) -> np.ndarray:
    """Column order in which independent columns are picked (earlier = kept)."""
    order = []
    for j in range(n_joints):
        order += [10 * j + k for k in reversed(range(len(INERTIAL_PARAMETERS)))]
    order += list(range(10 * n_joints, len(names)))
    return np.array(order)


def _fmt(c: float) -> str:
    return f"{abs(c):.6g}"


def _label(names: tuple[str, ...], row: np.ndarray, kept: int) -> str:
    terms = [names[kept]]
    for i in np.flatnonzero(row):
        if i == kept:
            continue
        c = row[i]
        sign = "−" if c < 0 else "+"
        terms.append(
            f"{sign} {names[i]}" if np.isclose(abs(c), 1.0, rtol=1e-9) else f"{sign} {_fmt(c)}·{names[i]}"
        )
    return " ".join(terms)


@dataclass(frozen=True, eq=False)
class BaseParameterSet:
    """The identifiable combinations p_b = K·p of the full parameters p (names `full_names`).

    `independent[i]` is the full-parameter index kept as base parameter i (its K row has 1 there);
    Y_b = Y[:, independent]. `unidentifiable` lists parameters without any effect on τ.
    Conditioning: `rank_tolerance` (relative, on the unit-column QR diagonal), `r_min_kept` and
    `r_max_dropped` (the two sides of the rank gap) and `cond` (2-norm condition number of the unit-column
    base regressor on the random samples: a property of the robot, not of an excitation).
    """

    full_names: tuple[str, ...]
    independent: np.ndarray
    K: np.ndarray
    names: tuple[str, ...]
    labels: tuple[str, ...]
    unidentifiable: tuple[str, ...] = ()
    rank_tolerance: float = RANK_TOLERANCE
    r_min_kept: float = float("nan")
    r_max_dropped: float = float("nan")
    cond: float = float("nan")
    n_samples: int = 0
    seed: int = 0

    def __post_init__(self) -> None:
        for f in ("independent", "K"):
            a = np.array(getattr(self, f), dtype=int if f == "independent" else float)
            a.setflags(write=False)
            object.__setattr__(self, f, a)
        nb = len(self.independent)
        if self.K.shape != (nb, len(self.full_names)) or len(self.names) != nb or len(self.labels) != nb:
            raise ValueError("inconsistent base parameter set shapes")

    @property
    def n_base(self) -> int:
        return len(self.independent)

    def project(self, p: np.ndarray | DynamicParameters) -> np.ndarray:
        """p_b = K·p."""
        p = p.vector() if isinstance(p, DynamicParameters) else np.asarray(p, dtype=float)
        return self.K @ p

    def base_regressor(self, y: np.ndarray) -> np.ndarray:
        """Y_b = the kept columns of a full regressor Y (τ = Y_b·p_b)."""
        return y[:, self.independent]

    def combination(self, i: int) -> dict[str, float]:
        """Base parameter i as {full parameter name: coefficient}."""
        return {self.full_names[j]: float(self.K[i, j]) for j in np.flatnonzero(self.K[i])}

    @classmethod
    def from_combinations(
        cls,
        full_names: tuple[str, ...],
        names: list[str],
        kept: list[str],
        combinations: list[dict[str, float]],
    ) -> BaseParameterSet:
        """Rebuild a set from stored combinations (e.g. a dynamics.yaml artefact)."""
        index = {n: i for i, n in enumerate(full_names)}
        k = np.zeros((len(names), len(full_names)))
        for i, combo in enumerate(combinations):
            for name, c in combo.items():
                if name not in index:
                    raise InputError(f"base parameter {names[i]!r} refers to unknown parameter {name!r}")
                k[i, index[name]] = c
        missing = [kp for kp in kept if kp not in index]
        if missing:
            raise InputError(f"unknown independent parameters {missing}")
        independent = np.array([index[kp] for kp in kept], dtype=int)
        if np.any(np.abs(k[np.arange(len(names)), independent] - 1.0) > 1e-12):
            raise InputError("each base parameter must contain its independent parameter with coefficient 1")
        labels = tuple(_label(full_names, k[i], independent[i]) for i in range(len(names)))
        return cls(
            full_names=tuple(full_names), independent=independent, K=k, names=tuple(names), labels=labels
        )


def base_parameters(
    robot: Robot, n_samples: int = 300, seed: int = 0, rank_tolerance: float = RANK_TOLERANCE
) -> BaseParameterSet:
    """The base parameter set of `robot` from `n_samples` random states within its limits (≥ 50: the
    rank must not depend on the sample)."""
    if n_samples < 50:
        raise ValueError(f"n_samples must be at least 50 for a reliable rank, got {n_samples}")
    q, qd, qdd = random_states(robot, n_samples, seed)
    w = joint_torque_regressor(robot, q, qd, qdd)
    names = parameter_names(robot.joint_names, robot.drives.spring is not None, robot.has_motor_friction)
    return base_parameters_from_regressor(w, names, robot.n, rank_tolerance, n_samples=n_samples, seed=seed)


def regrouping(w_kept: np.ndarray, w_dropped: np.ndarray) -> np.ndarray:
    """κ [kept × dropped] with W_dropped ≈ W_kept·κ: the least squares, except for a column it does
    not reproduce exactly (`EXACT_DEPENDENCE`), which is regrouped greedily (the kept column most
    aligned with what remains first) on the fewest columns that bring its residual within
    `SPARSE_SLACK` of the least squares' (module docstring)."""
    kappa = np.linalg.lstsq(w_kept, w_dropped, rcond=None)[0]
    norms = np.maximum(np.linalg.norm(w_kept, axis=0), 1e-300)
    for d in range(w_dropped.shape[1]):
        col = w_dropped[:, d]
        size = float(np.linalg.norm(col))
        full = float(np.linalg.norm(col - w_kept @ kappa[:, d]))
        if size == 0.0 or full <= EXACT_DEPENDENCE * size:
            continue
        chosen: list[int] = []
        rest = col
        while len(chosen) < w_kept.shape[1]:
            score = np.abs(w_kept.T @ rest) / norms
            score[chosen] = -1.0
            chosen.append(int(np.argmax(score)))
            c = np.linalg.lstsq(w_kept[:, chosen], col, rcond=None)[0]
            rest = col - w_kept[:, chosen] @ c
            if np.linalg.norm(rest) <= (1.0 + SPARSE_SLACK) * full:
                break
        kappa[:, d] = 0.0
        kappa[chosen, d] = c
    return kappa


def base_parameters_from_regressor(
    w: np.ndarray,
    names: tuple[str, ...],
    n_joints: int,
    rank_tolerance: float = RANK_TOLERANCE,
    *,
    n_samples: int = 0,
    seed: int = 0,
) -> BaseParameterSet:
    """The base parameter set for a stacked regressor `w` (rows: samples × joints, columns: `names`)."""
    norms = np.linalg.norm(w, axis=0)
    nonzero = norms > _ZERO_COLUMN * norms.max()
    wn = np.zeros_like(w)
    wn[:, nonzero] = w[:, nonzero] / norms[nonzero]

    # Rank from the pivoted QR (rank-revealing).
    r_piv = sla.qr(wn[:, nonzero], mode="r", pivoting=True)[0]
    d_piv = np.abs(np.diag(r_piv))
    rank = int(np.sum(d_piv > rank_tolerance * d_piv[0]))

    # Kept columns: greedy in preference order (|R_ii| of the unpivoted QR = residual of column i
    # after projecting out all columns before it).
    order = np.array([i for i in _preference_order(names, n_joints) if nonzero[i]])
    r_ord = sla.qr(wn[:, order], mode="r")[0]
    d_ord = np.abs(np.diag(r_ord))
    kept_mask = d_ord > rank_tolerance * d_piv[0]
    if int(kept_mask.sum()) != rank:
        raise ValueError(
            f"ordered QR keeps {int(kept_mask.sum())} columns, pivoted QR finds rank {rank}: "
            "the regressor samples are degenerate; use more samples"
        )
    independent = np.sort(order[kept_mask])
    dropped = np.array([i for i in range(len(names)) if i not in set(independent)], dtype=int)

    w1 = w[:, independent]
    kappa = regrouping(w1, w[:, dropped])
    # Coefficients that contribute nothing (relative to the dropped column's norm) are rounding noise.
    contrib = np.abs(kappa) * norms[independent][:, None] / np.maximum(norms[dropped], 1e-300)[None, :]
    kappa[contrib < _COEFF_CLEAN] = 0.0
    kappa[:, ~nonzero[dropped]] = 0.0
    k = np.zeros((len(independent), len(names)))
    k[np.arange(len(independent)), independent] = 1.0
    k[:, dropped] = kappa

    base_names, labels = [], []
    for i, j in enumerate(independent):
        regrouped = np.count_nonzero(k[i]) > 1
        base_names.append(f"{names[j]}_R" if regrouped else names[j])
        labels.append(_label(names, k[i], j))
    return BaseParameterSet(
        full_names=tuple(names),
        independent=independent,
        K=k,
        names=tuple(base_names),
        labels=tuple(labels),
        unidentifiable=tuple(names[i] for i in np.flatnonzero(~nonzero)),
        rank_tolerance=rank_tolerance,
        r_min_kept=float(d_piv[rank - 1] / d_piv[0]),
        r_max_dropped=float(d_piv[rank] / d_piv[0]) if rank < len(d_piv) else 0.0,
        cond=float(np.linalg.cond(wn[:, independent])),
        n_samples=n_samples,
        seed=seed,
    )


def parameter_scale(names: tuple[str, ...], p0: np.ndarray, n_joints: int) -> np.ndarray:
    """Typical magnitude per parameter: |p0_i|, floored for parameters whose prior is (near) zero. Link
    floors scale with the link: first moments m·5 cm, inertias 5 % of the mean diagonal inertia."""
    scale = np.abs(np.asarray(p0, dtype=float)).copy()
    for j in range(n_joints):
        link = p0[10 * j : 10 * j + 10]
        mass, diag = abs(link[0]), abs(link[4]) + abs(link[6]) + abs(link[9])
        floors = [0.0] + [0.05 * mass] * 3 + [0.05 * diag / 3] * 6
        scale[10 * j : 10 * j + 10] = np.maximum(scale[10 * j : 10 * j + 10], floors)
    for i in range(10 * n_joints, len(names)):
        scale[i] = max(scale[i], _SCALE_FLOOR.get(_kind(names[i]), 1e-6))
    return np.maximum(scale, 1e-12)


def parameters_from_base(
    robot: Robot, bset: BaseParameterSet, p_b: np.ndarray, prior: DynamicParameters | None = None
) -> DynamicParameters:
    """A full parameter set reproducing the base values exactly (K·p = p_b): the prior with the minimum
    relative correction (see the module docstring)."""
    prior = prior_parameters(robot) if prior is None else prior.conform(robot)
    prior.check_robot(robot)
    names = parameter_names(robot.joint_names, prior.has_spring, prior.has_motor_friction)
    if tuple(bset.full_names) != names:
        raise InputError(f"base parameters are defined over other parameters than robot {robot.name!r} has")
    p_b = np.asarray(p_b, dtype=float)
    if p_b.shape != (bset.n_base,):
        raise InputError(f"expected {bset.n_base} base parameter values, got {p_b.shape}")
    p0 = prior.vector()
    s = parameter_scale(names, p0, robot.n)
    p = p0 + s * (np.linalg.pinv(bset.K * s[None, :], rcond=1e-12) @ (p_b - bset.K @ p0))
    return DynamicParameters.from_vector(robot.joint_names, p, prior.has_spring, prior.has_motor_friction)


def dynamics_from_artefact(artefact: Dynamics, robot: Robot) -> DynamicParameters:
    """The parameters a `schemas.dynamics.Dynamics` artefact stands for, on `robot`: its full estimate
    when it carries one, else the prior corrected to its base parameter values."""
    names = parameter_names(robot.joint_names, robot.drives.spring is not None, robot.has_motor_friction)
    if tuple(artefact.robot_joints) != robot.joint_names:
        raise InputError(
            f"dynamics are for joints {artefact.robot_joints}, the robot has {list(robot.joint_names)}",
            field="robot_joints",
        )
    if artefact.full_parameters is not None:
        return DynamicParameters.from_dict(robot, artefact.full_parameters)
    bps = artefact.base_parameters
    bset = BaseParameterSet.from_combinations(
        names, [b.name for b in bps], [b.independent for b in bps], [b.combination for b in bps]
    )
    return parameters_from_base(robot, bset, np.array([b.value for b in bps]))


class FittedDynamics(NamedTuple):
    """Identified parameters and the robot they are a model on: `robot` has the kinematics of the fit
    (the calibrated ones after `identify --calibration`), so τ(q, q̇, q̈) is `params` on `robot`."""

    params: DynamicParameters
    robot: Robot


def fitted_kinematics(artefact: Dynamics, robot: Robot, file: str | Path | None = None) -> Robot:
    """`robot` (nominal) with the geometric errors of the kinematics `artefact` was fitted on, if any."""
    if artefact.kinematics_errors is None:
        return robot
    from rxcomm.model.geometric_errors import ErrorModel

    f = None if file is None else str(file)
    errors = ErrorModel.from_mapping(robot, artefact.kinematics_errors, file=f, field="kinematics_errors")
    return errors.apply(robot)


def load_dynamics(path: str | Path, robot: Robot) -> FittedDynamics:
    """Read `dynamics.yaml` (kind rxcomm/Dynamics) for the NOMINAL `robot`: its parameters and the robot
    to evaluate τ(q, q̇, q̈) on, which carries the kinematics of the fit (architecture §6.1): a model
    fitted on calibrated axes predicts the validation log 2–4× worse on the nominal ones."""
    from rxcomm.model.artefact_checks import check_consistent, check_same_robot

    art = read_yaml_artefact(path, Dynamics)
    check_same_robot(robot, art.inputs, path)
    try:
        fitted = fitted_kinematics(art, robot, path)
        params = dynamics_from_artefact(art, fitted)
    except InputError as e:
        raise InputError(e.reason, file=path, field=e.field) from e
    check_consistent(fitted, params, path)
    return FittedDynamics(params, fitted)


def dynamics_artefact_fields(
    robot: Robot,
    bset: BaseParameterSet,
    p_b: np.ndarray,
    relative_std: np.ndarray | None = None,
    full: DynamicParameters | None = None,
    full_method: str | None = None,
    std: np.ndarray | None = None,
) -> dict:
    """The data fields of a `schemas.dynamics.Dynamics` artefact (everything but the envelope)."""
    p_b = np.asarray(p_b, dtype=float)
    params = full if full is not None else parameters_from_base(robot, bset, p_b)
    params.check_robot(robot)
    if full is not None and not np.allclose(bset.project(full), p_b, rtol=1e-6, atol=1e-9):
        raise ValueError("the full estimate does not reproduce the base parameter values")
    rel = [None] * bset.n_base if relative_std is None else [float(v) for v in relative_std]
    sig = [None] * bset.n_base if std is None else [float(v) for v in std]
    spring = None
    if robot.drives.spring is not None:
        base_of = {int(j): i for i, j in enumerate(bset.independent)}
        i_kl0 = bset.full_names.index("spring.kL0")
        k_identified = bset.full_names.index("spring.k") in base_of
        # k alone regroups with link gravity: report the prior unless the set (or a full estimate
        # that says so) separates it; the loaded parameters may carry a corrected k all the same.
        k = params.spring[0] if (k_identified or full is not None) else robot.drives.spring.stiffness_n_per_m
        spring = {
            "joint": robot.drives.spring.joint,
            "k_l0_n": float(params.spring[1]),
            "k_l0_relative_std": rel[base_of[i_kl0]] if i_kl0 in base_of else None,
            "stiffness_n_per_m": float(k),
            "stiffness_identified": k_identified,
        }
    return {
        "robot": robot.name,
        "robot_joints": list(robot.joint_names),
        "parameter_names": list(bset.full_names),
        "base_set": {
            "n_full": len(bset.full_names),
            "n_base": bset.n_base,
            "rank_tolerance": bset.rank_tolerance,
            "r_min_kept": bset.r_min_kept,
            "r_max_dropped": bset.r_max_dropped,
            "cond": bset.cond,
            "n_samples": bset.n_samples,
            "seed": bset.seed,
            "unidentifiable": list(bset.unidentifiable),
        },
        "base_parameters": [
            {
                "name": bset.names[i],
                "label": bset.labels[i],
                "independent": bset.full_names[bset.independent[i]],
                "combination": bset.combination(i),
                "value": float(p_b[i]),
                "relative_std": rel[i],
                "std": sig[i],
            }
            for i in range(bset.n_base)
        ],
        "full_parameters": None if full is None else full.as_dict(),
        "full_parameters_method": full_method,
        "friction": [
            {
                "joint": j,
                "coulomb_nm": float(params.coulomb_nm[i]),
                "viscous_nm_s_per_rad": float(params.viscous_nm_s_per_rad[i]),
                "offset_nm": float(params.offset_nm[i]),
                "motor_coulomb_nm": (
                    float(params.motor_coulomb_nm[i]) if params.has_motor_friction else None
                ),
                "motor_viscous_nm_s_per_rad": (
                    float(params.motor_viscous_nm_s_per_rad[i]) if params.has_motor_friction else None
                ),
            }
            for i, j in enumerate(robot.joint_names)
        ],
        "spring": spring,
    }
