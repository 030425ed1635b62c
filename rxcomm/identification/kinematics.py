"""The kinematics a dynamics fit runs on (architecture §1, §6.1): nominal or calibrated.

A robot's torques depend on its real joint axes. Fitting them on the nominal kinematics when the arm
moves on other axes biases the base parameters (on the MuJoCo plant, whose bodies carry the truth's
geometric errors, joint_3.mcz_R by 26σ on the RX130L): `identify --calibration` fits on the
calibrated kinematics instead.

Geometric errors break the structural dependencies of the nominal regressor (an axis tilted by 1 mrad
makes 4 more RX130L parameters "identifiable" at a condition number of 3600), so the base set keeps the
nominal robot's columns and names and its regrouping K is computed on the calibrated kinematics
(`base_set_on`), with one exception (`tilt_columns`): a parameter WITHOUT effect on the nominal robot
(a zero column there, `unidentifiable`) that has one on the calibrated kinematics, independent of the
kept columns, is kept too. On a first axis tilted from gravity (base and J1 errors, a few mrad) that is
link 1's first moment across the axis: g·θ·(mcx, mcy) turned by q1, a J1 torque no nominal column can
express (the masses at the shoulder offset and link 2's first moment along its axis regroup into it).
Regrouped by least squares over random states it averages out there, but not along an excitation
that swings J1 over part of a turn: on the M900's MuJoCo logs (θ ≈ 4 mrad, 0.07 N·m rms of J1's torque
unexplained) it put j1.offset 10σ off on a 1.5 rad swing, and j1.fc / j1.fv −7.2σ / +6.6σ on a 5.4 rad
one (architecture §6.1). Kept unless the log cannot condition them: along a J1 swing of a few degrees
that torque is nearly constant, J1's friction offset (`identify_on` then keeps those it determines).
And kept only where they lower J1's cross-validated held-out error: conditioned is not determined
(MuJoCo Menagerie's WidowX AI, no armature: 19.8 ± 39.7 and 14.4 ± 26.3 kg·m on a 0.15 kg link, J1's
validation error 0.222 N·m against 0.028 regrouped, and a fit 245σ from any body). A
nonzero column the nominal set regroups that these kinematics separate (`separated_columns`: the
RX130L's balancer k, regrouped with link 2's gravity on the nominal axes, 1.3e-3 apart on tilted ones)
is kept only where the log determines it (`identify_on`: σ ≤ 1/3 of its value within `max_cond`):
such a separation sits near the rank tolerance, so the data decide, not the tolerance, and a log
that cannot resolve it is fitted with it regrouped instead of refused.

`inertials_in_frames_of` scores such a fit: a calibration fixes the joint axis lines, not where each
link frame sits on them, so the bodies' inertials must be expressed in the calibrated link frames
before they compare with the estimate (tests, `bench.plant_compare`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.model.base_parameters import BaseParameterSet, regrouping
from rxcomm.model.dynamics import DynamicParameters, joint_torque_regressor, random_states
from rxcomm.model.robot import Robot

if TYPE_CHECKING:
    from rxcomm.identification.fit import Identification
    from rxcomm.identification.logs import JointLog
    from rxcomm.identification.settings import IdentifySettings

# Regrouping coefficients whose torque is below this fraction of the dropped column's are rounding
# noise of the least squares (the nominal set's own cleaning is 1e-10 on exact dependencies).
_COEFF_CLEAN = 1e-9
# A column below this fraction of the largest has no effect (as `rxcomm.model.base_parameters` decides).
_ZERO_COLUMN = 1e-10


def tilt_columns(w: np.ndarray, nominal: BaseParameterSet) -> np.ndarray:
    """Full-parameter indices without effect on the nominal robot (`nominal.unidentifiable`) whose column
    of the regressor `w` (another kinematics') has one, independent of the nominal set's kept columns and
    of those taken before it: relative residual above the nominal set's rank tolerance, as its QR on unit
    columns decides; taken in the nominal set's name order (link 1's first moments first)."""
    norms = np.linalg.norm(w, axis=0)
    taken: list[int] = []
    for name in nominal.unidentifiable:
        i = nominal.full_names.index(name)
        if norms[i] <= _ZERO_COLUMN * norms.max():
            continue
        basis = w[:, np.concatenate([nominal.independent, taken]).astype(int)]
        resid = w[:, i] - basis @ np.linalg.lstsq(basis, w[:, i], rcond=None)[0]
        if np.linalg.norm(resid) > nominal.rank_tolerance * norms[i]:
            taken.append(i)
    return np.array(taken, dtype=int)


def separated_columns(
    robot: Robot, nominal: BaseParameterSet, n_samples: int = 300, seed: int = 0
) -> tuple[str, ...]:
    """Parameters the nominal set regroups (nonzero columns, dependent on its kept ones) that `robot`'s
    kinematics separate: relative residual against the kept columns and `tilt_columns` above the
    nominal set's rank tolerance, largest first (the RX130L's balancer k on tilted axes, 1.3e-3)."""
    w = _regressor(robot, nominal, n_samples, seed)
    norms = np.linalg.norm(w, axis=0)
    basis = w[:, np.concatenate([nominal.independent, tilt_columns(w, nominal)]).astype(int)]
    found: list[tuple[float, str]] = []
    for i, name in enumerate(nominal.full_names):
        if (
            i in nominal.independent
            or name in nominal.unidentifiable
            or norms[i] <= _ZERO_COLUMN * norms.max()
        ):
            continue
        resid = w[:, i] - basis @ np.linalg.lstsq(basis, w[:, i], rcond=None)[0]
        if (rel := float(np.linalg.norm(resid) / norms[i])) > nominal.rank_tolerance:
            found.append((rel, name))
    return tuple(name for _, name in sorted(found, reverse=True))


def _regressor(robot: Robot, nominal: BaseParameterSet, n_samples: int, seed: int) -> np.ndarray:
    q, qd, qdd = random_states(robot, n_samples, seed)
    w = joint_torque_regressor(robot, q, qd, qdd)
    if w.shape[1] != len(nominal.full_names):
        raise ValueError("the base set is over other parameters than the robot has")
    return w


def tilted_names(
    robot: Robot, nominal: BaseParameterSet, n_samples: int = 300, seed: int = 0
) -> tuple[str, ...]:
    """The names of `tilt_columns` on `robot`'s kinematics over its random states."""
    w = _regressor(robot, nominal, n_samples, seed)
    return tuple(nominal.full_names[i] for i in tilt_columns(w, nominal))


def base_set_on(
    robot: Robot,
    nominal: BaseParameterSet,
    n_samples: int = 300,
    seed: int = 0,
    keep: tuple[str, ...] = (),
    tilt: tuple[str, ...] | None = None,
) -> BaseParameterSet:
    """`nominal`'s base parameters (same kept columns, same names) regrouped on `robot`'s kinematics:
    K[:, dropped] = lstsq(W_kept, W_dropped) over random states of `robot`; plus the parameters these
    kinematics give an effect the nominal robot's do not (`tilt_columns`, module docstring; only those
    named in `tilt` when given) and those named in `keep` (`separated_columns` a log determines:
    `identify_on`), named as the nominal set names its own (`_R` when regrouped). On the nominal
    kinematics: the nominal set."""
    w = _regressor(robot, nominal, n_samples, seed)
    tilted = [i for i in tilt_columns(w, nominal) if tilt is None or nominal.full_names[i] in tilt]
    extra = [nominal.full_names.index(k) for k in keep]
    kept = np.unique(np.concatenate([nominal.independent, tilted, extra]).astype(int))
    dropped = np.setdiff1d(np.arange(w.shape[1]), kept)
    kappa = regrouping(w[:, kept], w[:, dropped])  # sparse where a tilt separates a column
    norms = np.linalg.norm(w, axis=0)
    contrib = np.abs(kappa) * norms[kept][:, None] / np.maximum(norms[dropped], 1e-300)[None, :]
    kappa[contrib < _COEFF_CLEAN] = 0.0
    k = np.zeros((len(kept), w.shape[1]))
    k[np.arange(len(kept)), kept] = 1.0
    k[:, dropped] = kappa
    names = nominal.full_names
    combos = [{names[j]: float(k[i, j]) for j in np.flatnonzero(k[i])} for i in range(len(kept))]
    nominal_name = dict(zip(nominal.independent.tolist(), nominal.names, strict=True))
    base_names = [
        nominal_name.get(j, names[j] + ("_R" if np.count_nonzero(k[i]) > 1 else ""))
        for i, j in enumerate(kept.tolist())
    ]
    regrouped = BaseParameterSet.from_combinations(names, base_names, [names[j] for j in kept], combos)
    return replace(regrouped, n_samples=n_samples, seed=seed, rank_tolerance=nominal.rank_tolerance)


class KinematicsFit(NamedTuple):
    """`identify_on`'s result: the identification, its base set, and the `tilt_columns` fitted
    regrouped because the log could not condition them all and did not determine these (the user is
    told: their effect sits in J1's friction offset)."""

    identification: Identification
    base_set: BaseParameterSet
    regrouped: tuple[str, ...]


def identify_on(
    robot: Robot,
    nominal: BaseParameterSet,
    log: JointLog,
    settings: IdentifySettings,
    validation_log: JointLog | None = None,
) -> KinematicsFit:
    """Identify on `robot`'s (calibrated) kinematics with `base_set_on`'s set, each of the
    `separated_columns` kept as well where the log determines it: σ ≤ 1/3 of its value (3σ from zero)
    within `max_cond`; else it stays regrouped as on the nominal robot (module docstring).

    The `tilt_columns` are kept where they lower J1's cross-validated held-out error (where the fit
    has folds), unless the log cannot condition them within `max_cond`: along a J1
    swing of a few degrees link 1's first moment across the axis turns J1 by a nearly constant torque,
    the column of J1's friction offset (the imported UR5e's MuJoCo excitation: cond 2.4e4 on
    mcy_R/offset). Then the fit starts from none and keeps each one the log determines, as above, in
    order: kept but undetermined, such a column's value can be tens of times the truth's, and its
    torque varies with J1's angle beyond the logged swing, where regrouped it is a constant error of
    the true term's size. A log that cannot be fitted with none of them is refused as before."""
    from rxcomm.identification.fit import identify

    def fit(bset: BaseParameterSet) -> Identification:
        return identify(robot, log, settings, validation_log=validation_log, bset=bset)

    def determined(trial: BaseParameterSet, name: str) -> Identification | None:
        """The fit with `name`'s column kept where the log determines it (3σ from zero in `max_cond`)."""
        try:
            res = fit(trial)
        except (InputError, np.linalg.LinAlgError):  # the log cannot condition it (cond, singular)
            return None
        i = int(np.flatnonzero(trial.independent == nominal.full_names.index(name))[0])
        return res if res.estimate.relative_std[i] <= 1.0 / 3.0 else None

    def j1_cv_rms(res: Identification | None) -> float:
        cv = None if res is None else res.cross_validation
        return math.inf if cv is None or not np.isfinite(cv.rms_nm[0]) else float(cv.rms_nm[0])

    tilt = candidates = tilted_names(robot, nominal)
    bset = base_set_on(robot, nominal)
    try:
        result = fit(bset)
        if tilt and result.cross_validation is not None:
            # kept only where they lower J1's held-out error (module docstring)
            plain = base_set_on(robot, nominal, tilt=())
            try:
                alt: Identification | None = fit(plain)
            except (InputError, np.linalg.LinAlgError):
                alt = None
            if j1_cv_rms(alt) < j1_cv_rms(result):
                result, bset, tilt = alt, plain, ()
    except (InputError, np.linalg.LinAlgError):
        if not tilt:
            raise
        tilt = ()
        bset = base_set_on(robot, nominal, tilt=tilt)
        result = fit(bset)
        for name in candidates:
            trial = base_set_on(robot, nominal, tilt=(*tilt, name))
            if (res := determined(trial, name)) is not None:
                result, bset, tilt = res, trial, (*tilt, name)
    kept: tuple[str, ...] = ()
    for name in separated_columns(robot, nominal):
        trial = base_set_on(robot, nominal, keep=(*kept, name), tilt=tilt)
        if (res := determined(trial, name)) is not None:
            kept, bset, result = (*kept, name), trial, res
    return KinematicsFit(result, bset, tuple(n for n in candidates if n not in tilt))


def inertials_in_frames_of(
    moving: Robot, frames: Robot, params: DynamicParameters, n_samples: int = 50
) -> tuple[DynamicParameters, np.ndarray]:
    """`params` (link inertials about `moving`'s link frames) about `frames`' link frames, and the
    largest spread of the frame offset over the sampled poses (‖log6‖, rad or m: small when both
    robots turn about the same axes, e.g. the truth's geometry and a calibration of it)."""
    qs = random_states(frames, n_samples, 3)[0]
    da, db = moving.model.createData(), frames.model.createData()
    offsets = np.empty((n_samples, moving.n, 6))
    for s, q in enumerate(qs):
        pin.forwardKinematics(moving.model, da, q)
        pin.forwardKinematics(frames.model, db, q)
        for j in range(moving.n):
            offsets[s, j] = pin.log6(db.oMi[j + 1].inverse() * da.oMi[j + 1]).vector
    mean = offsets.mean(axis=0)
    spread = float(np.max(np.abs(offsets - mean)))
    inertial = np.array(
        [
            pin.exp6(mean[j]).act(pin.Inertia.FromDynamicParameters(params.inertial[j])).toDynamicParameters()
            for j in range(moving.n)
        ]
    )
    return replace(params, inertial=inertial), spread
