"""Foundation rows: the per-sample cost of the model calls every stage is built on, beside bare Pinocchio."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from bench.ik_before import lm_from_seed, multi_start_before
from bench.table import Row, median_cpu_seconds, median_seconds
from rxcomm.model.dynamics import RobotDynamics, joint_torque_regressor, prior_parameters, random_states
from rxcomm.model.geometric_errors import identification_jacobians
from rxcomm.model.ik import ik_solutions
from rxcomm.model.kinematics import inverse_kinematics, tcp_placement
from rxcomm.model.robot import load_robot
from rxcomm.model.symbolic import inverse_dynamics_function


def rows(quick: bool) -> list[Row]:
    robot = load_robot("samples/rx130l")
    n = 200 if quick else 2000
    repeats = 3 if quick else 7
    q, qd, qdd = random_states(robot, n, seed=1)
    params = prior_parameters(robot)
    dyn = RobotDynamics(robot, params)
    model, data = robot.model, robot.create_data()

    def bare_regressor():
        for i in range(n):
            pin.computeJointTorqueRegressor(model, data, q[i], qd[i], qdd[i])

    def bare_rnea():
        for i in range(n):
            pin.rnea(model, data, q[i], qd[i], qdd[i])

    ours_y = median_seconds(lambda: joint_torque_regressor(robot, q, qd, qdd), repeats) / n
    peer_y = median_seconds(bare_regressor, repeats) / n
    ours_id = median_seconds(lambda: dyn.inverse_dynamics(q, qd, qdd), repeats) / n
    peer_id = median_seconds(bare_rnea, repeats) / n
    f = inverse_dynamics_function(robot, params).map(n)
    ours_ca = median_seconds(lambda: f(q.T, qd.T, qdd.T), repeats) / n
    ours_jac = median_seconds(lambda: identification_jacobians(robot, q), repeats) / n

    targets = [tcp_placement(robot, q[i]) for i in range(min(n, 50))]
    rng = np.random.default_rng(2)
    seeds = [np.clip(q[i] + rng.normal(0, 0.05, 6), robot.q_min, robot.q_max) for i in range(len(targets))]

    def ik_all():
        for tgt, s in zip(targets, seeds, strict=True):
            assert inverse_kinematics(robot, tgt, s).ok

    def ik_before():
        for tgt, s in zip(targets, seeds, strict=True):
            lm_from_seed(robot, tgt, s)

    ours_ik = median_cpu_seconds(ik_all, repeats) / len(targets)
    before_ik = median_cpu_seconds(ik_before, repeats) / len(targets)
    ik_data = robot.create_data()
    n_t = len(targets)
    branches = median_cpu_seconds(lambda: [ik_solutions(robot, t, ik_data) for t in targets], repeats) / n_t
    few = targets[: 3 if quick else 10]
    multi = median_cpu_seconds(lambda: [multi_start_before(robot, ik_data, t, 96) for t in few], 1) / len(few)
    return [
        Row(
            "foundation",
            "joint-torque regressor + drives columns, per sample",
            "s",
            ours_y,
            peer_name="bare pin regressor",
            peer=peer_y,
        ),
        Row(
            "foundation",
            "inverse dynamics (RNEA + rotor, friction, spring), per sample",
            "s",
            ours_id,
            peer_name="bare pin.rnea",
            peer=peer_id,
        ),
        Row(
            "foundation",
            "CasADi inverse dynamics (mapped), per sample",
            "s",
            ours_ca,
            peer_name="bare pin.rnea",
            peer=peer_id,
        ),
        Row("foundation", "identification Jacobian 6×48, per pose", "s", ours_jac),
        Row(
            "foundation",
            "IK from a seed 0.05 rad away, per pose (CPU time)",
            "s",
            ours_ik,
            peer_name="projected LM from the seed (the IK before)",
            peer=before_ik,
            target="≤ 50 µs (264 µs in issue 32)",
        ),
        Row(
            "foundation",
            "IK, every branch of a pose (closed form + Newton; CPU time)",
            "s",
            branches,
            peer_name="96-start Newton search (the IK before)",
            peer=multi,
            target="≤ 1 ms (a 96-start search 74 ms in issue 32)",
        ),
    ]
