"""CasADi inverse dynamics and forward kinematics agree with Pinocchio and `rxcomm.model.dynamics`."""

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest

from rxcomm.model.dynamics import (
    COULOMB_EPS_NLP_RAD_S,
    DynamicParameters,
    inverse_dynamics,
    joint_torque_regressor,
    prior_parameters,
    random_states,
)
from rxcomm.model.symbolic import (
    forward_kinematics_function,
    inverse_dynamics_function,
    parametric_inverse_dynamics_function,
    regressor_function,
    rnea_expr,
)


def perturbed(robot, seed=9):
    rng = np.random.default_rng(seed)
    p0 = prior_parameters(robot)
    p = p0.vector() * rng.uniform(0.7, 1.3, p0.vector().shape)
    p[13 * robot.n : 14 * robot.n] = rng.normal(0, 5, robot.n)
    return DynamicParameters.from_vector(robot.joint_names, p, p0.has_spring, p0.has_motor_friction)


def test_casadi_rnea_matches_pinocchio(robot):
    q, qd, qdd = (ca.SX.sym(s, robot.n) for s in ("q", "qd", "qdd"))
    inertial = [robot.model.inertias[i].toDynamicParameters() for i in range(1, robot.n + 1)]
    f = ca.Function("rnea", [q, qd, qdd], [rnea_expr(robot, q, qd, qdd, inertial)])
    d = robot.create_data()
    qs, qds, qdds = random_states(robot, 50, seed=21)
    err = max(
        np.abs(
            np.array(f(qs[i], qds[i], qdds[i])).ravel() - pin.rnea(robot.model, d, qs[i], qds[i], qdds[i])
        ).max()
        for i in range(50)
    )
    assert err <= 1e-9, err


@pytest.mark.parametrize("eps", [None, COULOMB_EPS_NLP_RAD_S])
def test_casadi_inverse_dynamics_matches_numeric(robot, eps):
    params = perturbed(robot)
    f = inverse_dynamics_function(robot, params, coulomb_eps_rad_s=eps)
    assert f.name_in() == ["q", "qd", "qdd"] and f.name_out() == ["tau"]
    q, qd, qdd = random_states(robot, 200, seed=22)
    qd[:5] *= 1e-3  # near-zero speeds: the smooth Coulomb branch matters
    tau_ca = np.array(f.map(200)(q.T, qd.T, qdd.T)).T
    tau = inverse_dynamics(robot, params, q, qd, qdd, coulomb_eps_rad_s=eps)
    assert np.abs(tau_ca - tau).max() <= 1e-9
    # Parametric form with the same numbers.
    fp = parametric_inverse_dynamics_function(robot, coulomb_eps_rad_s=eps)
    assert fp.name_in() == ["q", "qd", "qdd", "p"]
    tau_p = np.array(fp(q[0], qd[0], qdd[0], params.vector())).ravel()
    assert np.abs(tau_p - tau[0]).max() <= 1e-9


def test_casadi_regressor_matches_numeric(robot):
    fy = regressor_function(robot)
    q, qd, qdd = random_states(robot, 10, seed=23)
    y = joint_torque_regressor(robot, q, qd, qdd).reshape(10, robot.n, -1)
    for i in range(10):
        yc = np.array(fy(q[i], qd[i], qdd[i]))
        np.testing.assert_allclose(yc, y[i], rtol=1e-10, atol=1e-9)


def test_casadi_forward_kinematics_matches_pinocchio(robot):
    fk = forward_kinematics_function(robot)
    assert fk.name_in() == ["q"] and fk.name_out() == ["p", "R"]
    d = robot.create_data()
    qs, _, _ = random_states(robot, 30, seed=24)
    for q in qs:
        pin.framesForwardKinematics(robot.model, d, q)
        m = d.oMf[robot.tcp_frame_id]
        p, r = fk(q)
        np.testing.assert_allclose(np.array(p).ravel(), m.translation, atol=1e-12)
        np.testing.assert_allclose(np.array(r), m.rotation, atol=1e-12)
