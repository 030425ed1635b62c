"""Commanding through the calibrated joint compliance (rxcomm.calibration.compensation): poses at rest
and CP plans (rxcomm.planning.commanded)."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rxcomm.calibration.compensation import encoder_angles
from rxcomm.calibration.compliance import holding_torques
from rxcomm.io.yaml_io import load_yaml
from rxcomm.model.dynamics import prior_parameters

from .artefacts import synthetic_calibration

SAMPLES = Path(__file__).resolve().parent.parent / "samples"
ISO_LINE = SAMPLES / "rx130l/paths/iso9283-line.yaml"


def test_encoder_angles_put_the_links_at_the_pose(rx130l):
    c = np.zeros(6)
    c[1], c[2] = 1.0e-6, 1.8e-6  # J2/J3 as the chain's calibration finds them, rad/(N·m)
    q_link = np.array([0.3, 0.9, 0.6, 0.2, 0.8, -0.4])  # arm reaching forward: J2/J3 loaded
    q = encoder_angles(rx130l, q_link, c)
    # the calibration's model of the link angle: q − c·τ(q) with the prior holding torque at q
    back = q - c * holding_torques(rx130l, q)[0]
    np.testing.assert_allclose(back, q_link, atol=1e-12)
    tau = holding_torques(rx130l, q_link)[0]
    assert abs(tau[1]) > 50 and q[1] - q_link[1] == pytest.approx(c[1] * tau[1], rel=1e-3)
    np.testing.assert_array_equal(q[[0, 3, 4, 5]], q_link[[0, 3, 4, 5]])  # rigid joints as solved
    np.testing.assert_array_equal(encoder_angles(rx130l, q_link, np.zeros(6)), q_link)


# --- CP plans commanded through the compliance (rxcomm.planning.commanded) ----------------------------

C_J2_J3 = np.array([0.0, 1.0e-6, 1.8e-6, 0.0, 0.0, 0.0])  # rad/(N·m), as the chain's calibration finds


def test_commanded_velocity_and_acceleration_are_the_time_derivatives(rx130l):
    """q̇_cmd, q̈_cmd by the chain rule against central differences in time of E(q(t)) at a fine step."""
    from rxcomm.calibration.compensation import encoder_map
    from rxcomm.planning.commanded import commanded_trajectory

    enc = encoder_map(rx130l, C_J2_J3)
    a, b, w = np.array([0.3, 0.9, 0.6, 0.2, 0.8, -0.4]), np.array([0.5, -0.4, 0.6, 1.0, 0.3, 0.7]), 2.0
    t = np.linspace(0.1, 1.5, 15)
    h = 1e-4

    def link(t):
        s = np.sin(w * t)[:, None]
        return a + b * s, b * w * np.cos(w * t)[:, None], -b * w**2 * s

    q, qd, qdd = link(t)
    qc, qdc, qddc = commanded_trajectory(enc, q, qd, qdd)
    np.testing.assert_allclose(qc - C_J2_J3 * holding_torques(rx130l, qc), q, atol=1e-13)
    up, mid, down = enc(link(t + h)[0]), enc(q), enc(link(t - h)[0])
    np.testing.assert_allclose(qdc, (up - down) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(qddc, (up - 2 * mid + down) / h**2, atol=3e-7)
    # the compensation moves them measurably (2e-5 rad/s, 1e-4 rad/s² here): the checks above can fail
    assert np.abs(qdc - qd).max() > 1e-5 and np.abs(qddc - qdd).max() > 5e-5
    rest = commanded_trajectory(enc, q[:1], np.zeros((1, 6)), np.zeros((1, 6)))
    assert not rest[1].any() and not rest[2].any()  # at rest the commanded motion is exactly zero


@pytest.fixture(scope="module")
def line_plans(rx130l):
    """The ISO line (toppra timing, fast) planned rigid, with zero compliance and with J2/J3's."""
    from rxcomm.calibration.compensation import encoder_map
    from rxcomm.planning.cp import CpSettings, plan_cp
    from rxcomm.planning.paths import build_path
    from rxcomm.planning.timing import PlanDynamics
    from rxcomm.schemas.path import PathSpec

    path = build_path(PathSpec.model_validate(load_yaml(ISO_LINE)))
    settings = CpSettings(method="toppra", torque_rate=False, intervals=120)
    dyn = PlanDynamics.from_parameters(rx130l, prior_parameters(rx130l), settings.coulomb_eps_rad_s)
    return {
        name: plan_cp(rx130l, path, dyn, settings, command=cmd)
        for name, cmd in (
            ("rigid", None),
            ("zero", encoder_map(rx130l, np.zeros(6))),
            ("compliant", encoder_map(rx130l, C_J2_J3)),
        )
    }, dyn


def test_compensated_cp_plan_puts_the_links_on_the_ik_within_limits(rx130l, line_plans):
    from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE, check_limits, robot_limits

    plans, dyn = line_plans
    plan = plans["compliant"]
    q_link = plan.joint_path(plan.sigma)  # the calibrated (here: nominal) IK along the path
    np.testing.assert_allclose(plan.q - C_J2_J3 * holding_torques(rx130l, plan.q), q_link, atol=1e-9)
    np.testing.assert_array_equal(plan.link_angles, q_link)
    offset = plan.q - q_link
    assert 2e-4 < np.abs(offset[:, 1:3]).max() < 2e-3 and not offset[:, [0, 3, 4, 5]].any()
    # q̇, q̈ consistent with q: the offset's derivatives against differences at the drive cycle
    dt = rx130l.drives.cycle_s
    rigid = plans["rigid"]
    assert plan.duration_s == pytest.approx(rigid.duration_s, rel=0.05)
    d_off = np.gradient(offset, dt, axis=0)
    jp = plan.joint_path
    qd_link = jp(plan.sigma, 1) * plan.sigma_dot[:, None]
    np.testing.assert_allclose((plan.qd - qd_link)[1:-1], d_off[1:-1], atol=1e-6)
    # every joint limit on the streamed samples with run's model torque (toppra: no torque rate)
    tau = dyn.smooth(plan.q, plan.qd, plan.qdd)
    np.testing.assert_array_equal(tau, plan.tau)
    report = check_limits(
        rx130l, plan.t, plan.q, plan.qd, plan.qdd, tau, robot_limits(rx130l, torque_rate=False)
    )
    assert report.max_ratio <= 1 + SAMPLED_LIMIT_TOLERANCE
    assert plan.report.max_ratio <= 1 + SAMPLED_LIMIT_TOLERANCE


def test_zero_compliance_leaves_the_cp_plan_unchanged_bit_for_bit(line_plans):
    plans, _ = line_plans
    rigid, zero = plans["rigid"], plans["zero"]
    for name in ("t", "sigma", "sigma_dot", "q", "qd", "qdd", "tau"):
        np.testing.assert_array_equal(getattr(zero, name), getattr(rigid, name))
    assert rigid.q_link is None


ERRORS = {"joint_2.tx": 0.003, "joint_3.ry": 0.004}  # a calibration's geometric errors


def _calibration(robot, summary: dict):
    """A calibration whose chosen model found C_J2_J3 (with `summary` entries, e.g. its torque model)."""
    compliance = {"joint_2": C_J2_J3[1], "joint_3": C_J2_J3[2]}
    return synthetic_calibration(robot, ERRORS, compliance=compliance, summary=summary)


@pytest.mark.slow
def test_plan_cp_stage_compensates_the_calibrated_compliance(tmp_path, rx130l):
    """--calibration whose chosen model found J2/J3 compliance (prior torque model): the streamed q
    puts the links on the calibrated IK, so the calibrated TCP of the LINKS follows the path, while
    the encoders' own angles are the deflection off it; the compliances are recorded."""
    import pinocchio as pin

    from rxcomm.io.trajectory import load_trajectory_mcap
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.model.geometric_errors import ErrorModel
    from rxcomm.planning.paths import build_path
    from rxcomm.schemas.path import PathSpec
    from rxcomm.stages import plan_cp as stage

    errors = ERRORS
    cal = _calibration(rx130l, {"compliance_torque_model": "prior"})
    cal_file = write_yaml_artefact(tmp_path / "calibration.yaml", cal)
    out = tmp_path / "line.mcap"
    stage.command(SAMPLES / "rx130l", ISO_LINE, out, calibration=cal_file, method="toppra", torque_rate=False)
    traj, env = load_trajectory_mcap(out)
    assert env["settings"]["compliance_compensated_rad_per_nm"] == pytest.approx(C_J2_J3.tolist())
    calibrated = ErrorModel.from_mapping(rx130l, errors).apply(rx130l)
    path = build_path(PathSpec.model_validate(load_yaml(ISO_LINE)))
    idx = np.arange(0, traj.n, 50)
    q_link = traj.q[idx] - C_J2_J3 * holding_torques(rx130l, traj.q[idx])
    d = calibrated.create_data()
    err_link, err_enc = [], []
    for q, errs in ((q_link, err_link), (traj.q[idx], err_enc)):
        for qi, s in zip(q, traj.extra["sigma"][idx], strict=True):
            pin.framesForwardKinematics(calibrated.model, d, qi)
            errs.append(np.linalg.norm(d.oMf[calibrated.tcp_frame_id].translation - path.position([s])[0]))
    assert max(err_link) < 1e-6 < 1e-4 < max(err_enc)  # the links on the path; the encoders 0.1 mm+ off


def test_compliance_is_commanded_with_the_torque_model_the_fit_used(rx130l):
    """calibrate records its torque model in the summary: identified → the given dynamics (required),
    prior → the prior; the commanded deflection differs by the models' holding-torque ratio."""
    from rxcomm.calibration.compensation import compliance_command, compliance_torque_params
    from rxcomm.errors import InputError

    cal = _calibration(rx130l, {"compliance_torque_model": "identified"})
    with pytest.raises(InputError, match="--dynamics"):
        compliance_torque_params(cal, None)
    prior = prior_parameters(rx130l)
    heavier = replace(prior, inertial=prior.inertial * 1.1)
    assert compliance_torque_params(cal, heavier) is heavier
    q_link = np.array([[0.3, 0.9, 0.6, 0.2, 0.8, -0.4]])
    enc, c = compliance_command(rx130l, cal, heavier)
    enc_prior, _ = compliance_command(
        rx130l, _calibration(rx130l, {"compliance_torque_model": "prior"}), heavier
    )
    assert c == pytest.approx(C_J2_J3.tolist())
    ratio = (enc(q_link) - q_link)[0, 1:3] / (enc_prior(q_link) - q_link)[0, 1:3]
    assert ratio[1] == pytest.approx(1.1, rel=1e-3)  # J3 carries the 10 % heavier links' weight only
    assert abs(ratio[0] - 1.0) > 0.02  # J2: weight and balancer spring (not scaled)


@pytest.mark.slow
def test_time_optimal_circle_commanded_through_the_compliance_stays_within_what_run_accepts(rx130l):
    """The path NLP's plan of the large ISO circle at 0.4 m/s (a time-optimal plan: limits at 1.00x)
    with J2/J3 compensated: every joint limit, torque rate included, re-checked on the streamed
    samples with run's model torque stays within run's tolerance, the links on the IK."""
    from rxcomm.calibration.compensation import encoder_map
    from rxcomm.model.limits import SAMPLED_LIMIT_TOLERANCE, check_limits, robot_limits
    from rxcomm.planning.cp import CpSettings, plan_cp
    from rxcomm.planning.paths import build_path
    from rxcomm.planning.timing import PlanDynamics
    from rxcomm.schemas.path import PathSpec

    path = build_path(PathSpec.model_validate(load_yaml(SAMPLES / "rx130l/paths/iso9283-circle-large.yaml")))
    settings = CpSettings(tcp_speed_max_m_s=0.4)
    dyn = PlanDynamics.from_parameters(rx130l, prior_parameters(rx130l), settings.coulomb_eps_rad_s)
    plan = plan_cp(rx130l, path, dyn, settings, command=encoder_map(rx130l, C_J2_J3))
    np.testing.assert_allclose(
        plan.q - C_J2_J3 * holding_torques(rx130l, plan.q), plan.joint_path(plan.sigma), atol=1e-9
    )
    tau = dyn.smooth(plan.q, plan.qd, plan.qdd)
    report = check_limits(rx130l, plan.t, plan.q, plan.qd, plan.qdd, tau, robot_limits(rx130l))
    assert report.max_ratio <= 1 + SAMPLED_LIMIT_TOLERANCE
    assert max(report.max_by_limit()[k] for k in ("acceleration", "torque_rate")) > 0.98  # time-optimal
