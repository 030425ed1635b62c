"""calibrate on data as it comes (issue 16): frames found from the data, noise known or estimated,
the model chosen by cross-validation, sanity checks (angle convention, worse than nominal), the one
reach figure, and gravity-induced joint compliance (truth read here only to score)."""

import numpy as np
import pinocchio as pin
import pytest
from typer.testing import CliRunner

from rxcomm.calibration.fit import calibrate
from rxcomm.calibration.measurements import MeasurementSet, read_measurements
from rxcomm.calibration.pose_selection import select_measurement_poses
from rxcomm.calibration.settings import CalibrateSettings
from rxcomm.cell.tracker import SimulatedTracker
from rxcomm.cli import app
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.model.dynamics import RobotDynamics, truth_parameters
from rxcomm.model.geometric_errors import predict_poses, random_poses
from rxcomm.model.kinematics import cardan_xyz
from rxcomm.model.robot import load_robot
from rxcomm.schemas.calibration import Calibration

from .conftest import SAMPLES
from .test_calibration import _load, _measure

ROBOT = SAMPLES / "rx130l"


def _truth_with(truth, **errors):
    ep = dict(truth.geometry.error_parameters)
    for k, v in errors.items():
        ep[k.replace("_", ".", 1)] = ep.get(k.replace("_", ".", 1), 0.0) + v
    return truth.model_copy(update={"geometry": truth.geometry.model_copy(update={"error_parameters": ep})})


@pytest.fixture(scope="module")
def robot():
    return load_robot(ROBOT)


@pytest.fixture(scope="module")
def tool_off(robot):
    """A campaign whose real TCP is 10 cm (x) and 5 cm (z) from drives.yaml's, 60 random poses."""
    _, truth, t2b = _load("rx130l")
    tracker = SimulatedTracker(
        robot, _truth_with(truth, tool_tx=0.10, tool_tz=0.05), np.random.default_rng(5)
    )
    qs = random_poses(robot, 60, np.random.default_rng(3))
    return t2b, tracker, _measure(tracker, qs, ["fit"] * 40 + ["validation"] * 20)


@pytest.mark.slow  # 2.9 s CPU (make test-fast: the unit tier within 60 s)
def test_frames_from_the_data_need_no_guess(robot, tool_off):
    """Tool 10 cm off, base guessed 180° (yaw) and 10 cm away, or rough (10 cm / 10°), or no guess:
    the same calibration as with the exact base, pose and position-only alike."""
    t2b, tracker, ms = tool_off
    flipped = t2b * pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.0, np.pi), np.array([0.1, 0.0, 0.0]))
    rough = t2b * pin.SE3(pin.rpy.rpyToMatrix(0.0, 0.1, 0.17), np.array([0.1, 0.05, 0.0]))
    true = np.array([tracker.true_pose(q).translation for q in ms.q])
    for data in (ms, MeasurementSet(ms.q, ms.position_m, None, ms.valid, ms.role)):
        exact = calibrate(robot, data, tracker_to_base=t2b)
        assert exact.tracker_to_base_source == "cell"
        assert any("tool (TCP) is 10" in n for n in exact.notes)  # the tool offset is named
        p_exact, _ = predict_poses(robot, ms.q, exact.fit.errors, t2b)
        for guess in (flipped, rough, None):
            res = calibrate(robot, data, tracker_to_base=guess)
            assert res.tracker_to_base_source == "registration"
            if guess is not None:
                assert any("from where the measurements put it" in n for n in res.notes)
            p, _ = predict_poses(robot, ms.q, res.fit.errors, res.tracker_to_base)
            assert np.max(np.linalg.norm(p - p_exact, axis=1)) < 1e-6  # the same model
        held = exact.tables[("heldout", "calibrated")]
        assert held.max_position_error_m < 0.6e-3  # (position-only of the TCP origin: 27 → 25 params)
        assert np.max(np.linalg.norm(p_exact - true, axis=1)) < 0.6e-3


@pytest.mark.slow
def test_wrong_angle_convention_is_an_error(tmp_path, robot, tool_off):
    """Roll-pitch-yaw pasted into the Cardan columns: refused with the convention named; the same
    angles under roll/pitch/yaw columns calibrate."""
    t2b, _, ms = tool_off
    rpy = np.array([pin.rpy.matrixToRpy(r) for r in ms.rotation])
    head = "q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m,{},role"
    for cols, ok in (("alpha_rad,beta_rad,gamma_rad", False), ("roll_rad,pitch_rad,yaw_rad", True)):
        lines = [head.format(cols)]
        for i in range(ms.n):
            lines.append(
                ",".join(f"{v:.15g}" for v in [*ms.q[i], *ms.position_m[i], *rpy[i]]) + f",{ms.role[i]}"
            )
        path = tmp_path / "t.csv"
        path.write_text("\n".join(lines) + "\n")
        got = read_measurements(path, robot)
        if ok:
            np.testing.assert_allclose(got.rotation, ms.rotation, atol=1e-12)
            assert calibrate(robot, got).tables[("heldout", "calibrated")].max_position_error_m < 0.3e-3
        else:
            assert got.angle_convention == "cardan_xyz"
            with pytest.raises(InputError, match="angle convention"):
                calibrate(robot, got)
    # Quaternion columns read as such.
    qt = [pin.Quaternion(r) for r in ms.rotation]
    lines = [head.format("qw,qx,qy,qz")]
    for i in range(ms.n):
        vals = [*ms.q[i], *ms.position_m[i], qt[i].w, qt[i].x, qt[i].y, qt[i].z]
        lines.append(",".join(f"{v:.15g}" for v in vals) + f",{ms.role[i]}")
    path.write_text("\n".join(lines) + "\n")
    np.testing.assert_allclose(read_measurements(path, robot).rotation, ms.rotation, atol=1e-12)
    assert np.allclose(cardan_xyz(ms.rotation[:1]), cardan_xyz(read_measurements(path, robot).rotation[:1]))


@pytest.mark.slow
def test_worse_than_nominal_exits_3(tmp_path, robot):
    """The tracker moved 12 mm between the fit and the validation poses: the calibration absorbs the
    move and misses the held-out poses by more than the nominal model: exit 3, nothing written."""
    _, truth, t2b = _load("rx130l")
    tracker = SimulatedTracker(robot, truth, np.random.default_rng(8))
    ms = _measure(
        tracker, random_poses(robot, 60, np.random.default_rng(9)), ["fit"] * 40 + ["validation"] * 20
    )
    p = ms.position_m.copy()
    p[np.array(ms.role) == "fit"] += [0.012, 0.0, 0.0]
    moved = MeasurementSet(ms.q, p, ms.rotation, ms.valid, ms.role)
    with pytest.raises(InfeasibleError, match="worse than the nominal model"):
        calibrate(robot, moved, tracker_to_base=t2b)
    lines = ["q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m,role"]
    for i in range(ms.n):
        lines.append(",".join(f"{v:.15g}" for v in [*ms.q[i], *p[i]]) + f",{ms.role[i]}")
    path = tmp_path / "moved.csv"
    path.write_text("\n".join(lines) + "\n")
    cell = tmp_path / "cell.yaml"
    cell.write_text((ROBOT / "cell.yaml").read_text())
    out = tmp_path / "c.yaml"
    args = [
        "calibrate",
        "--robot",
        str(ROBOT),
        "--measurements",
        str(path),
        "--cell",
        str(cell),
        "-o",
        str(out),
    ]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 3, r.output
    assert "worse than the nominal" in r.output and not out.exists()


@pytest.mark.slow  # 0.8 s CPU (make test-fast: the unit tier within 60 s)
def test_tracker_sigma_option_and_estimated_noise(tmp_path, robot, tool_off):
    """--tracker-sigma without a cell file is used and recorded; without it the noise is estimated
    from the residuals (variance components), recorded and printed — never null."""
    t2b, _, ms = tool_off
    ang = cardan_xyz(ms.rotation)
    lines = ["q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m,alpha_rad,beta_rad,gamma_rad,role"]
    for i in range(ms.n):
        lines.append(",".join(f"{v:.15g}" for v in [*ms.q[i], *ms.position_m[i], *ang[i]]) + f",{ms.role[i]}")
    path = tmp_path / "t.csv"
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "c.yaml"
    base = ["calibrate", "--robot", str(ROBOT), "--measurements", str(path), "-o", str(out)]
    r = CliRunner().invoke(app, [*base, "--tracker-sigma", "2e-4,4e-4"])
    assert r.exit_code == 0, r.output
    art = read_yaml_artefact(out, Calibration)
    assert art.tracker_noise.model_dump() == {
        "position_sigma_m": 2e-4,
        "orientation_sigma_rad": 4e-4,
        "source": "option",
    }
    assert art.summary.tracker_position_sigma_m == 2e-4 and "tracker noise (option)" in r.output
    assert 0.15 < art.summary.residual_scale < 0.4  # the truth is 5e-5 / 1e-4: 4× smaller
    r = CliRunner().invoke(app, base)
    assert r.exit_code == 0, r.output
    art = read_yaml_artefact(out, Calibration)
    assert art.tracker_noise.source == "estimated" and "tracker noise (estimated)" in r.output
    assert art.tracker_noise.position_sigma_m == pytest.approx(5e-5, rel=0.25)
    assert art.tracker_noise.orientation_sigma_rad == pytest.approx(1e-4, rel=0.25)
    assert art.model_selection.chosen == "full" and len(art.model_selection.candidates) >= 3
    r = CliRunner().invoke(app, [*base, "--tracker-sigma", "-1"])
    assert r.exit_code == 2 and "tracker-sigma" in r.output


@pytest.mark.slow  # 1.6 s CPU (make test-fast: the unit tier within 60 s)
def test_camera_noise_few_poses_model_chosen_by_the_data(robot):
    """Camera-like noise (1 mm / 5 mrad), 17 fit poses, 6 held out, 5 seeded splits: the full
    30-parameter model overfits; the chosen model's held-out rms is no worse than frames-only (mean
    over splits), and poorly determined parameters are named."""
    _, truth, t2b = _load("rx130l")
    noisy = truth.model_copy(
        update={
            "noise": truth.noise.model_copy(
                update={"tracker_position_sigma_m": 1e-3, "tracker_orientation_sigma_rad": 5e-3}
            )
        }
    )
    chosen, frames = [], []
    for seed in range(5):
        tracker = SimulatedTracker(robot, noisy, np.random.default_rng(40 + seed))
        qs = random_poses(robot, 23, np.random.default_rng(60 + seed))
        ms = _measure(tracker, qs, ["fit"] * 17 + ["validation"] * 6)
        res = calibrate(robot, ms, tracker_to_base=t2b)
        assert res.noise.source == "estimated" and 0.4e-3 < res.noise.position_sigma_m < 2e-3
        chosen.append(res.tables[("heldout", "calibrated")].rms_position_error_m)
        frames.append(res.tables[("heldout", "frames_only")].rms_position_error_m)
        if res.model != "frames":
            assert res.undetermined  # 30 parameters from 17 noisy poses: some σ are large
    assert np.mean(chosen) <= np.mean(frames) * 1.0001, (chosen, frames)


def test_one_reach_figure(tmp_path, robot):
    """robot-info's reach is the unit check's."""
    r = CliRunner().invoke(app, ["robot-info", "--robot", str(ROBOT)])
    assert r.exit_code == 0 and f"{robot.reach_m:.3f} m" in r.output
    qs = random_poses(robot, 10, np.random.default_rng(0))
    p, _ = predict_poses(robot, qs)
    lines = ["q1_rad,q2_rad,q3_rad,q4_rad,q5_rad,q6_rad,x_m,y_m,z_m"]
    lines += [",".join(f"{v:.12g}" for v in [*qs[i], *(p[i] * 1000)]) for i in range(10)]
    path = tmp_path / "mm.csv"
    path.write_text("\n".join(lines) + "\n")
    reach = robot.reach_m
    with pytest.raises(InputError, match=f"reaches only ≈{reach:.2f} m"):
        read_measurements(path, robot)


@pytest.mark.slow
def test_joint_compliance_is_seen_and_modelled(robot):
    """The sample truth's J2/J3 stiffness (1.1e6 / 4.2e5 N·m/rad) bends the arm under gravity: the
    rigid model's held-out error rises above the compliance-free case, the chosen model (with
    compliance) brings the held-out rms back within 10 %, and the stiffness is recovered within 3σ
    of the truth as seen through the prior torques (k·τ_prior/τ_true, least squares over the poses:
    the deflection is τ_true/k, the model divides by τ_prior)."""
    cell, truth, t2b = _load("rx130l", rigid=False)
    rigid_truth = _load("rx130l")[1]
    k_true = truth.geometry.joint_stiffness_nm_per_rad
    assert set(k_true) == {"joint_2", "joint_3"}
    sel = select_measurement_poses(robot, cell, 32, max_candidates=4000, n_validation=32, restarts=3)
    qs = np.vstack([sel.q_selected, sel.q_validation])
    roles = ["fit"] * 32 + ["validation"] * 32
    settings = CalibrateSettings(position_sigma_m=5e-5, orientation_sigma_rad=1e-4)
    free = calibrate(
        robot,
        _measure(SimulatedTracker(robot, rigid_truth, np.random.default_rng(1)), qs, roles),
        settings,
        t2b,
    )
    tracker = SimulatedTracker(robot, truth, np.random.default_rng(1))
    ms = _measure(tracker, qs, roles)
    bent = calibrate(robot, ms, settings, tracker_to_base=t2b)
    rigid = calibrate(robot, ms, settings.model_copy(update={"model": "full"}), tracker_to_base=t2b)
    assert free.model == "full" and bent.model == "full+compliance"
    h_free = free.tables[("heldout", "calibrated")]
    h_rigid, h_bent = rigid.tables[("heldout", "calibrated")], bent.tables[("heldout", "calibrated")]
    assert h_rigid.max_position_error_m > 1.5 * h_free.max_position_error_m
    assert h_rigid.rms_position_error_m > 1.5 * h_free.rms_position_error_m
    assert h_bent.rms_position_error_m <= 1.10 * h_free.rms_position_error_m
    # the same rigid estimate to the round-off of its iterated weights (the priors' scale settles to 1 %)
    assert bent.tables[("heldout", "rigid")].max_position_error_m == pytest.approx(
        h_rigid.max_position_error_m, rel=1e-6
    )
    st = truth_parameters(robot, truth)
    tau_true = RobotDynamics(robot, st).gravity_torque(ms.q[:32])
    from rxcomm.calibration.compliance import holding_torques

    tau_prior = holding_torques(robot, ms.q[:32])
    for name, k in k_true.items():
        j = robot.joint_names.index(name)
        ratio = float(tau_prior[:, j] @ tau_true[:, j] / (tau_prior[:, j] @ tau_prior[:, j]))
        c, sd = bent.fit.compliance[j], bent.fit.compliance_std[j]
        assert abs(c - ratio / k) < 3 * sd, (name, 1 / c, k / ratio, sd / c**2)
        assert sd < 0.15 * c  # determined, not named
    assert not [n for n in bent.undetermined if n.endswith("compliance")]
    # With the true torques (as from an identified dynamics model) the stiffness is the truth's.
    exact = calibrate(robot, ms, settings, tracker_to_base=t2b, dynamics=st)
    assert exact.model == "full+compliance"
    for name, k in k_true.items():
        j = robot.joint_names.index(name)
        c, sd = exact.fit.compliance[j], exact.fit.compliance_std[j]
        assert abs(c - 1 / k) < 3 * sd, (name, 1 / c, k, sd / c**2)
