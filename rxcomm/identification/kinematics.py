"""The kinematics a dynamics fit runs on (architecture §1, §6.1): nominal or calibrated.

A robot's torques depend on its real joint axes. Fitting them on the nominal kinematics when the arm
moves on other axes biases the base parameters (on the MuJoCo plant, whose bodies carry the truth's
geometric errors, joint_3.mcz_R by 26σ on the RX130L): `identify --calibration` fits on the
calibrated kinematics instead.

Geometric errors break the structural dependencies of the nominal regressor (an axis tilted by 1 mrad
makes 4 more RX130L parameters "identifiable" at a condition number of 3600), so the base set keeps the
nominal robot's columns and names and only its regrouping K is computed on the calibrated kinematics
(`base_set_on`): the best 61-parameter model of the calibrated robot's torques.

`inertials_in_frames_of` scores such a fit: a calibration fixes the joint axis lines, not where each
link frame sits on them, so the bodies' inertials must be expressed in the calibrated link frames
before they compare with the estimate (tests, `bench.plant_compare`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from rxcomm.model.base_parameters import BaseParameterSet
from rxcomm.model.dynamics import DynamicParameters, joint_torque_regressor, random_states
from rxcomm.model.robot import Robot

# Regrouping coefficients whose torque is below this fraction of the dropped column's are rounding
# noise of the least squares (the nominal set's own cleaning is 1e-10 on exact dependencies).
_COEFF_CLEAN = 1e-9


def base_set_on(
    robot: Robot, nominal: BaseParameterSet, n_samples: int = 300, seed: int = 0
) -> BaseParameterSet:
    """`nominal`'s base parameters (same kept columns, same names) regrouped on `robot`'s kinematics:
    K[:, dropped] = lstsq(W_kept, W_dropped) over random states of `robot`."""
    q, qd, qdd = random_states(robot, n_samples, seed)
    w = joint_torque_regressor(robot, q, qd, qdd)
    if w.shape[1] != len(nominal.full_names):
        raise ValueError("the base set is over other parameters than the robot has")
    kept = nominal.independent
    dropped = np.setdiff1d(np.arange(w.shape[1]), kept)
    kappa = np.linalg.lstsq(w[:, kept], w[:, dropped], rcond=None)[0]
    norms = np.linalg.norm(w, axis=0)
    contrib = np.abs(kappa) * norms[kept][:, None] / np.maximum(norms[dropped], 1e-300)[None, :]
    kappa[contrib < _COEFF_CLEAN] = 0.0
    k = np.zeros_like(nominal.K)
    k[np.arange(len(kept)), kept] = 1.0
    k[:, dropped] = kappa
    names = nominal.full_names
    combos = [{names[j]: float(k[i, j]) for j in np.flatnonzero(k[i])} for i in range(len(kept))]
    regrouped = BaseParameterSet.from_combinations(
        names, list(nominal.names), [names[j] for j in kept], combos
    )
    return replace(regrouped, n_samples=n_samples, seed=seed, rank_tolerance=nominal.rank_tolerance)


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
