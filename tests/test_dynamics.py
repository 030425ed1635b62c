"""Dynamics with drives: regressor vs RNEA, spring physics, base parameters, dynamics.yaml round trip."""

import numpy as np
import pinocchio as pin
import pytest

from rxcomm.errors import InputError
from rxcomm.io.yaml_io import read_yaml_model, write_yaml_artefact
from rxcomm.model.base_parameters import (
    BaseParameterSet,
    base_parameters,
    dynamics_artefact_fields,
    load_dynamics,
    parameters_from_base,
    regrouping,
)
from rxcomm.model.dynamics import (
    COULOMB_EPS_NLP_RAD_S,
    DynamicParameters,
    RobotDynamics,
    forward_dynamics,
    gravity_torque,
    inverse_dynamics,
    joint_torque_regressor,
    mass_matrix,
    model_with_inertials,
    parameter_names,
    prior_parameters,
    random_states,
    truth_parameters,
)
from rxcomm.model.robot import load_robot
from rxcomm.model.spring import spring_length, spring_torque
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.truth import CellTruth

from .conftest import SAMPLES


def perturbed(robot, seed=7, rel=0.3):
    """Prior parameters scaled by random factors, with non-zero offsets: exercises every column."""
    rng = np.random.default_rng(seed)
    p0 = prior_parameters(robot)
    p = p0.vector() * rng.uniform(1 - rel, 1 + rel, p0.vector().shape)
    n = robot.n
    p[13 * n : 14 * n] = rng.normal(0, 5, n)
    return DynamicParameters.from_vector(robot.joint_names, p, p0.has_spring, p0.has_motor_friction)


@pytest.fixture(scope="module")
def bset_rx(rx130l):
    return base_parameters(rx130l, n_samples=300, seed=0)


def test_parameter_names_and_vector(rx130l, m900):
    names = parameter_names(rx130l.joint_names, True)
    assert len(names) == 86 and len(parameter_names(m900.joint_names, False)) == 84
    for name in (
        "joint_2.m",
        "joint_2.mcx",
        "joint_3.Ixx",
        "joint_4.rotor_inertia",
        "joint_1.fc",
        "spring.kL0",
    ):
        assert name in names
    p = prior_parameters(rx130l)
    d = p.as_dict()
    assert d["joint_2.m"] == pytest.approx(38.8) and d["joint_2.mcz"] == pytest.approx(38.8 * 0.3)
    assert d["spring.kL0"] == pytest.approx(7500 * 0.08) and d["joint_6.rotor_inertia"] == 2e-5
    # the RX130L's coupled wrist: friction "both" by default, 2 × 6 motor friction entries at the end
    assert rx130l.friction_mode == "both" and m900.friction_mode == "joint"
    assert p.names[-12:] == tuple(f"joint_{i}.{k}" for k in ("fc_motor", "fv_motor") for i in range(1, 7))
    back = DynamicParameters.from_vector(rx130l.joint_names, p.vector(), True, True)
    np.testing.assert_array_equal(back.vector(), p.vector())
    assert DynamicParameters.from_dict(rx130l, d).as_dict() == d
    with pytest.raises(ValueError):
        p.inertial[0, 0] = 1.0


def test_regressor_times_parameters_is_inverse_dynamics(robot):
    q, qd, qdd = random_states(robot, 100, seed=1)
    for params in (prior_parameters(robot), perturbed(robot)):
        tau = inverse_dynamics(robot, params, q, qd, qdd)
        y = joint_torque_regressor(robot, q, qd, qdd)
        assert y.shape == (100 * robot.n, len(params.names))
        err = np.abs(y @ params.vector() - tau.ravel()).max()
        assert err <= 1e-9, err
    # One sample: (n,) in, (n,) and (n, P) out.
    assert inverse_dynamics(robot, params, q[0], qd[0], qdd[0]).shape == (robot.n,)
    assert joint_torque_regressor(robot, q[0], qd[0], qdd[0]).shape == (robot.n, len(params.names))


def test_smooth_coulomb(rx130l):
    params = prior_parameters(rx130l)
    q = np.zeros(6)
    qdd = np.zeros(6)
    eps = COULOMB_EPS_NLP_RAD_S
    fc = rx130l.coulomb_prior
    fv = rx130l.viscous_prior
    for v, shape in ((eps, np.tanh(1.0)), (-2 * eps, -np.tanh(2.0)), (0.0, 0.0)):
        qd = np.full(6, v)
        base = inverse_dynamics(rx130l, params, q, np.zeros(6), qdd)
        smooth = inverse_dynamics(rx130l, params, q, qd, qdd, coulomb_eps_rad_s=eps)
        # At q=0 the arm is vertical: no Coriolis from a uniform small speed beyond O(v²).
        np.testing.assert_allclose(smooth - base, fc * shape + fv * v, atol=1e-3)
    exact = inverse_dynamics(rx130l, params, q, np.full(6, 1.0), qdd)
    smooth = inverse_dynamics(rx130l, params, q, np.full(6, 1.0), qdd, coulomb_eps_rad_s=eps)
    np.testing.assert_allclose(smooth, exact, atol=1e-9)  # tanh(50) == 1 in double


def test_spring_torque_is_the_derivative_of_its_energy(rx130l):
    spring = rx130l.drives.spring
    k, l0 = spring.stiffness_n_per_m, spring.free_length_m
    q = np.linspace(-2.3, 2.3, 41)
    h = 1e-6

    def energy(x):
        return 0.5 * k * (spring_length(spring, x) - l0) ** 2

    fd = (energy(q + h) - energy(q - h)) / (2 * h)
    np.testing.assert_allclose(spring_torque(spring, q, k, k * l0), fd, rtol=1e-6, atol=1e-6)
    # Shortest at q = -offset: length |a - b|.
    assert spring_length(spring, -spring.angle_offset_rad) == pytest.approx(0.1)


def test_gravity_matches_potential_energy_and_spring_balances_j2(rx130l):
    params = prior_parameters(rx130l)
    rd = RobotDynamics(rx130l, params)
    q = np.array([0.3, 1.1, -0.4, 0.7, 0.5, -0.2])
    h = 1e-6
    fd = np.empty(6)
    for i in range(6):
        dq = np.zeros(6)
        dq[i] = h
        fd[i] = (
            pin.computePotentialEnergy(rd.model, rd.data, q + dq)
            - pin.computePotentialEnergy(rd.model, rd.data, q - dq)
        ) / (2 * h)
    np.testing.assert_allclose(rd.gravity_torque(q, include_spring=False), fd, atol=1e-5)

    stretched = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0])
    g_arm = gravity_torque(rx130l, params, stretched, include_spring=False)[1]
    g_sprung = gravity_torque(rx130l, params, stretched)[1]
    print(f"\nRX130L J2 stretched horizontally: gravity {g_arm:.1f} N·m, with spring {g_sprung:.1f} N·m")
    assert abs(g_arm) == pytest.approx(527, abs=3)  # architecture §4
    assert abs(g_sprung) < abs(g_arm) - 300 and abs(g_sprung) < rx130l.tau_max[1]
    assert abs(g_arm) < rx130l.tau_max[1] < abs(g_arm) + 10 * 9.81 * 1.66  # 10 kg payload would exceed


def test_mass_matrix_forward_dynamics_and_coupled_rotors(robot):
    params = perturbed(robot)
    q, qd, qdd = random_states(robot, 20, seed=2)
    mm = mass_matrix(robot, params, q)
    assert mm.shape == (20, robot.n, robot.n)
    np.testing.assert_allclose(mm, np.swapaxes(mm, 1, 2), atol=1e-12)
    assert np.linalg.eigvalsh(mm).min() > 0
    # M is ∂τ/∂q̈ (τ is affine in q̈).
    e = np.eye(robot.n)
    tau0 = inverse_dynamics(robot, params, q, qd, np.zeros_like(qdd))
    cols = [
        inverse_dynamics(robot, params, q, qd, np.broadcast_to(e[j], qdd.shape)) - tau0
        for j in range(robot.n)
    ]
    np.testing.assert_allclose(np.stack(cols, axis=-1), mm, atol=1e-9)
    tau = inverse_dynamics(robot, params, q, qd, qdd)
    np.testing.assert_allclose(forward_dynamics(robot, params, q, qd, tau), qdd, atol=1e-9)
    # Prior rotors reproduce the robot's reflected (coupled) rotor inertia.
    rd = RobotDynamics(robot, prior_parameters(robot))
    np.testing.assert_allclose(rd.rotor_matrix, robot.reflected_rotor_inertia)


def test_model_with_inertials_builds_a_new_model(rx130l):
    before = rx130l.model.inertias[3].toDynamicParameters().copy()
    params = perturbed(rx130l)
    m = model_with_inertials(rx130l.model, params.inertial)
    np.testing.assert_allclose(m.inertias[3].toDynamicParameters(), params.inertial[2], rtol=1e-12)
    np.testing.assert_array_equal(rx130l.model.inertias[3].toDynamicParameters(), before)
    bad = params.inertial.copy()
    bad[1, 0] = 0.0
    with pytest.raises(InputError, match="mass is zero"):
        model_with_inertials(rx130l.model, bad)


def test_base_parameters_rx130l(rx130l, bset_rx):
    b = bset_rx
    print(
        f"\nRX130L: {b.n_base} base parameters of {len(b.full_names)}; |R_ii| gap {b.r_min_kept:.3g} / "
        f"{b.r_max_dropped:.3g}; cond (unit columns, random states) {b.cond:.2f}"
    )
    # 59 + the coupled motor 6's Coulomb and viscous friction; motors 1–5 regroup with their joints
    assert b.n_base == 61
    assert b.labels[b.names.index("joint_1.fc_R")] == "joint_1.fc + 180·joint_1.fc_motor"
    assert "joint_6.fc_motor" in b.names and "joint_6.fv_motor" in b.names and "joint_6.fc" in b.names
    assert b.r_min_kept > 1e-3 and b.r_max_dropped < 1e-12
    # 11 columns without effect: link 1 except Izz (vertical axis through its origin), m2 and mcy2
    # (link 2's origin lies on axis 1; mcy2 lies along axis 2).
    assert set(b.unidentifiable) == {
        f"joint_1.{x}" for x in ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz")
    } | {
        "joint_2.m",
        "joint_2.mcy",
    }
    combos = {b.names[i]: b.combination(i) for i in range(b.n_base)}
    # The spring's k·ab·sin(q2) column has the shape of link 2's gravity: k regroups onto mcz2 with
    # coefficient −ab/g; the k·L0 column (∝ sin q2 / L) stays a base parameter of its own.
    spring = rx130l.drives.spring
    ab_over_g = spring.fixed_pivot_m * spring.moving_pivot_m / 9.81
    assert combos["joint_2.mcz_R"]["spring.k"] == pytest.approx(-ab_over_g, rel=1e-9)
    assert combos["joint_2.mcz_R"]["joint_3.m"] == pytest.approx(0.625, rel=1e-9)
    assert combos["spring.kL0"] == {"spring.kL0": 1.0}
    # Rotor 1 merges with Izz1 (both only ever see q̈1), scaled by the squared gear ratio; so does
    # rotor 2 with link 2's inertia about its own axis. Rotors 3–6 (coupled 6 included) are separate.
    assert combos["joint_1.Izz_R"]["joint_1.rotor_inertia"] == pytest.approx(180**2, rel=1e-9)
    assert combos["joint_2.Iyy_R"]["joint_2.rotor_inertia"] == pytest.approx(180**2, rel=1e-9)
    for j in (3, 4, 5, 6):
        assert combos[f"joint_{j}.rotor_inertia"] == {f"joint_{j}.rotor_inertia": 1.0}
    for j in range(1, 7):
        assert combos[f"joint_{j}.offset"] == {f"joint_{j}.offset": 1.0}
        for f in ("fc", "fv"):
            if j == 6:  # motor 6 turns with joint 5: its friction is a direction of its own
                assert combos[f"joint_6.{f}"] == {f"joint_6.{f}": 1.0}
                assert combos[f"joint_6.{f}_motor"] == {f"joint_6.{f}_motor": 1.0}
            else:  # an uncoupled motor's friction is its joint's, scaled by N (Coulomb) or N² (viscous)
                scale = rx130l.gear_ratio[j - 1] ** (1 if f == "fc" else 2)
                assert combos[f"joint_{j}.{f}_R"] == pytest.approx(
                    {f"joint_{j}.{f}": 1.0, f"joint_{j}.{f}_motor": scale}, rel=1e-9
                )
    i = b.names.index("joint_2.mcz_R")
    assert b.labels[i].startswith("joint_2.mcz + 0.625·joint_3.m") and "− 0.00611621·spring.k" in b.labels[i]


def test_a_frame_tilted_by_rounding_keeps_the_base_set(rx130l, bset_rx, tmp_path):
    """Joint 2's frame tilted by 0.2 mrad (a model's 1.571 for π/2, as MuJoCo Menagerie's M1013 has it)
    makes its rotor inertia separable from link 2's inertia about its axis at |R_ii| ≈ 2.6e-4 only: no
    excitation conditions that, so it stays regrouped and the base set keeps its size."""
    import shutil

    robot_dir = tmp_path / "rx130l"
    shutil.copytree(SAMPLES / "rx130l", robot_dir)
    urdf = robot_dir / "rx130l.urdf"
    exact = '<child link="link_2"/>\n    <origin xyz="0 0 0" rpy="0 0 0"/>'
    assert exact in urdf.read_text()
    urdf.write_text(urdf.read_text().replace(exact, exact.replace('rpy="0 0 0"', 'rpy="0.0002 0 0"')))
    tilted = base_parameters(load_robot(robot_dir))
    assert tilted.n_base == bset_rx.n_base and "joint_2.rotor_inertia" not in tilted.names
    assert tilted.r_min_kept > 1e-2
    loose = base_parameters(load_robot(robot_dir), rank_tolerance=1e-8)  # the 2.6e-4 direction kept
    assert loose.n_base == bset_rx.n_base + 1 and loose.r_min_kept < 1e-3
    # regrouped on link 2's inertia about its axis, not spread over every kept column by the least
    # squares (986b64d: on all of them, friction and offsets included)
    rotor = tilted.full_names.index("joint_2.rotor_inertia")
    holders = [tilted.names[i] for i in np.flatnonzero(tilted.K[:, rotor])]
    assert 1 <= len(holders) <= 3 and all(h.startswith("joint_2.I") for h in holders), holders


def test_an_inexact_column_is_regrouped_on_few_columns_an_exact_one_as_it_is():
    """`regrouping`: a column 1e-3 away from 2·w0 is regrouped on w0 alone (the least squares over
    random rows puts a little of it on every column); an exact combination keeps its coefficients."""
    rng = np.random.default_rng(0)
    kept = rng.standard_normal((400, 8))
    near = 2.0 * kept[:, 0] + 1e-3 * np.linalg.norm(kept[:, 0]) * rng.standard_normal(400) / 20.0
    exact = 2.0 * kept[:, 0] - 0.5 * kept[:, 3]
    kappa = regrouping(kept, np.c_[near, exact])
    assert np.count_nonzero(np.linalg.lstsq(kept, near, rcond=None)[0]) == 8  # what it replaces
    assert np.flatnonzero(kappa[:, 0]).tolist() == [0] and kappa[0, 0] == pytest.approx(2.0, rel=1e-3)
    np.testing.assert_allclose(kappa[:, 1], [2.0, 0, 0, -0.5, 0, 0, 0, 0], atol=1e-12)


def test_base_parameters_reproduce_torques(robot):
    b = base_parameters(robot, n_samples=200, seed=3)
    expected = 61 if robot.drives.spring is not None else 58  # RX130L: + motor 6 friction
    assert b.n_base == expected
    with pytest.raises(ValueError):
        base_parameters(robot, n_samples=10)
    q, qd, qdd = random_states(robot, 200, seed=11)  # fresh states
    y = joint_torque_regressor(robot, q, qd, qdd)
    for params in (prior_parameters(robot), perturbed(robot, seed=5)):
        p = params.vector()
        err = np.abs(b.base_regressor(y) @ b.project(p) - y @ p).max()
        assert err <= 1e-9, err


def test_parameters_from_base_and_artefact_round_trip(rx130l, bset_rx, tmp_path):
    truth = read_yaml_model(SAMPLES / "rx130l" / "truth.yaml", CellTruth)
    true = truth_parameters(rx130l, truth)
    p_b = bset_rx.project(true)
    rebuilt = parameters_from_base(rx130l, bset_rx, p_b)
    np.testing.assert_allclose(bset_rx.project(rebuilt), p_b, rtol=1e-10, atol=1e-10)
    assert np.all(rebuilt.inertial[:, 0] > 0)
    q, qd, qdd = random_states(rx130l, 50, seed=4)
    tau_true = inverse_dynamics(rx130l, true, q, qd, qdd)
    assert np.abs(inverse_dynamics(rx130l, rebuilt, q, qd, qdd) - tau_true).max() <= 1e-9

    fields = dynamics_artefact_fields(rx130l, bset_rx, p_b, relative_std=np.full(bset_rx.n_base, 0.01))
    summary = {"n_base_params": bset_rx.n_base, "validation_nrmse": [0.0] * 6, "validation_rms_nm": [0.0] * 6}
    art = Dynamics(**Dynamics.envelope({}, {}, {**summary, "seconds": 0.0}), **fields)
    assert art.spring.k_l0_n == pytest.approx(true.spring[1]) and not art.spring.stiffness_identified
    assert art.spring.stiffness_n_per_m == rx130l.drives.spring.stiffness_n_per_m  # k: the prior
    assert [f.coulomb_nm for f in art.friction] == pytest.approx(list(true.coulomb_nm))
    path = write_yaml_artefact(tmp_path / "dynamics.yaml", art)
    loaded, on = load_dynamics(path, rx130l)
    assert on is rx130l  # fitted on the nominal kinematics: evaluated on them
    assert np.abs(inverse_dynamics(rx130l, loaded, q, qd, qdd) - tau_true).max() <= 1e-9
    # Rebuilt from stored combinations: the same set.
    again = BaseParameterSet.from_combinations(
        bset_rx.full_names,
        [x.name for x in art.base_parameters],
        [x.independent for x in art.base_parameters],
        [x.combination for x in art.base_parameters],
    )
    np.testing.assert_array_equal(again.K, bset_rx.K)
    # A full estimate takes precedence.
    art_full = Dynamics(**{**art.model_dump(), **dynamics_artefact_fields(rx130l, bset_rx, p_b, full=true)})
    full_path = write_yaml_artefact(tmp_path / "full.yaml", art_full)
    np.testing.assert_allclose(load_dynamics(full_path, rx130l).params.vector(), true.vector())


def test_load_dynamics_refuses_another_robot(rx130l, m900, bset_rx, tmp_path):
    fields = dynamics_artefact_fields(rx130l, bset_rx, bset_rx.project(prior_parameters(rx130l)))
    summary = {
        "n_base_params": 59,
        "validation_nrmse": [0.0] * 6,
        "validation_rms_nm": [0.0] * 6,
        "seconds": 0.0,
    }
    path = write_yaml_artefact(tmp_path / "d.yaml", Dynamics(**Dynamics.envelope({}, {}, summary), **fields))
    with pytest.raises(InputError) as e:
        load_dynamics(path, m900)
    assert e.value.file == str(path) and e.value.field == "robot_joints"
    bad = dict(fields)
    bad["base_parameters"] = [dict(fields["base_parameters"][0], combination={"joint_1.Izz": 2.0})]
    with pytest.raises(ValueError):
        Dynamics(**Dynamics.envelope({}, {}, summary), **bad)
