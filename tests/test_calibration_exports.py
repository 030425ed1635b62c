"""Exports a controller or another tool takes: the calibrated URDF's TCP frame, the MDH tables and
zero offsets (the truth's error parameters are read here only to build a known calibration)."""

import csv

import numpy as np
import pinocchio as pin
import pytest
import yaml

from rxcomm.calibration.exports import kinematics_artefact, kinematics_csv, write_kinematics
from rxcomm.calibration.urdf import calibrated_urdf_text
from rxcomm.io.yaml_io import read_yaml_artefact
from rxcomm.model.geometric_errors import ErrorModel, joint_offset_names, random_poses
from rxcomm.model.kinematics import tcp_placement
from rxcomm.model.robot import load_robot
from rxcomm.schemas.kinematics import Kinematics, MdhForm

from .conftest import SAMPLES


def _truth_errors(robot, name):
    truth = yaml.safe_load((SAMPLES / name / "truth.yaml").read_text())
    return ErrorModel.from_mapping(robot, truth["geometry"]["error_parameters"])


@pytest.fixture(scope="module", params=["rx130l", "m900"])
def calibrated(request):
    robot = load_robot(SAMPLES / request.param)
    errors = _truth_errors(robot, request.param)
    return robot, errors, kinematics_artefact(robot, errors, {})


def _craig_fk(form: MdhForm, qs: np.ndarray) -> np.ndarray:
    """Craig's MDH chain written out independently of rxcomm.model.mdh: [N, 4, 4]."""

    def se3(p):
        return pin.SE3(pin.rpy.rpyToMatrix(np.array(p.rpy_rad)), np.array(p.xyz_m)).homogeneous

    def rot(axis, a):
        m = np.eye(4)
        m[:3, :3] = pin.exp3(a * np.eye(3)[axis])
        return m

    def tr(v):
        m = np.eye(4)
        m[:3, 3] = v
        return m

    out = []
    for q in qs:
        t = se3(form.base)
        for j, row in enumerate(form.joints):
            t = t @ rot(0, row.alpha_rad) @ rot(1, row.beta_rad) @ tr([row.a_m, 0, 0])
            t = t @ rot(2, q[j] + row.theta_offset_rad) @ tr([0, 0, row.d_m])
        out.append(t @ se3(form.tool))
    return np.array(out)


def _errors_vs(robot, errors, form, qs):
    """(max position m, max orientation rad) of `form` against the calibrated model's FK."""
    t = _craig_fk(form, qs)
    dp, do = 0.0, 0.0
    for k, q in enumerate(qs):
        ref = tcp_placement(robot, q, errors)
        dp = max(dp, float(np.linalg.norm(t[k, :3, 3] - ref.translation)))
        do = max(do, float(np.linalg.norm(pin.log3(ref.rotation.T @ t[k, :3, :3]))))
    return dp, do


def test_calibrated_urdf_has_the_tcp_frame_at_the_calibrated_tcp(tmp_path, calibrated):
    robot, errors, _ = calibrated
    path = tmp_path / "calibrated.urdf"
    path.write_text(calibrated_urdf_text(robot, errors))
    model = pin.buildModelFromUrdf(str(path))  # what RViz/Foxglove see: no drives.yaml involved
    data = model.createData()
    fid = model.getFrameId("tcp")
    assert fid < len(model.frames) and model.frames[fid].name == "tcp"
    worst, nominal_gap = 0.0, 0.0
    for q in random_poses(robot, 50, np.random.default_rng(3)):
        pin.framesForwardKinematics(model, data, q)
        ref = tcp_placement(robot, q, errors)
        worst = max(worst, float(np.max(np.abs(data.oMf[fid].homogeneous - ref.homogeneous))))
        nominal_gap = max(
            nominal_gap, float(np.linalg.norm(tcp_placement(robot, q).translation - ref.translation))
        )
    assert worst < 1e-9
    assert nominal_gap > 1e-3  # the calibration moves the TCP by mm: the frame carries it
    # The flange stays where drives.yaml's tcp expects it: the robot loaded from this URDF agrees too.
    cal_robot = load_robot(robot.drives_path.parent, urdf=path)
    q = random_poses(robot, 1, np.random.default_rng(4))[0]
    np.testing.assert_allclose(
        tcp_placement(cal_robot, q).homogeneous, tcp_placement(robot, q, errors).homogeneous, atol=1e-9
    )


def test_mdh_export_reproduces_the_calibrated_fk_to_the_residual_it_states(calibrated):
    robot, errors, art = calibrated
    fresh = random_poses(robot, 100, np.random.default_rng(11))  # not the poses the export used
    # Nominal: MDH is exact (J2 ∥ J3 by design).
    assert _errors_vs(robot, None, art.nominal, fresh)[0] < 1e-12
    # Plain MDH cannot follow the calibrated J2/J3 tilt: a real loss, stated, and no larger on new poses.
    stated = art.mdh.max_position_residual_m, art.mdh.max_orientation_residual_rad
    assert stated[0] > 1e-4 and art.parallel_pairs == [(robot.joint_names[1], robot.joint_names[2])]
    got = _errors_vs(robot, errors, art.mdh, fresh)
    assert got[0] <= 1.2 * stated[0] and got[1] <= 1.2 * stated[1]
    assert got[0] > 0.3 * stated[0]  # the stated figure is the loss, not a bound far above it
    # With Hayati's β on J3 the calibrated kinematics are exact again, and the export says 0, not
    # the fit's round-off (it wrote 7.55e-13 mm into the report before).
    assert art.mdh_beta.max_position_residual_m == 0.0 == art.nominal.max_position_residual_m
    assert art.mdh_beta.max_orientation_residual_rad == 0.0 == art.nominal.max_orientation_residual_rad
    assert _errors_vs(robot, errors, art.mdh_beta, fresh)[0] < 1e-9
    assert art.mdh_beta.joints[2].beta_rad != 0 and all(j.beta_rad == 0 for j in art.mdh.joints)


def test_zero_offsets_are_the_encoder_offsets_of_an_offsets_only_calibration():
    robot = load_robot(SAMPLES / "rx130l")
    offsets = dict(zip(joint_offset_names(robot), [0.0, 2e-3, -1.5e-3, 1e-3, -0.5e-3, 0.0], strict=True))
    art = kinematics_artefact(robot, ErrorModel.from_mapping(robot, offsets), {})
    got = {z.joint: z.offset_rad for z in art.zero_offsets}
    for name, value in offsets.items():
        assert got[name.split(".")[0]] == pytest.approx(value, abs=1e-9)
    # Offsets keep J2 ∥ J3: plain MDH is exact.
    assert art.mdh.max_position_residual_m == 0.0


def test_yaml_and_csv_round_trip(tmp_path, calibrated):
    robot, _, art = calibrated
    y, c = write_kinematics(tmp_path / "mdh.yaml", art)
    back = read_yaml_artefact(y, Kinematics)
    assert back.mdh.max_position_residual_m == art.mdh.max_position_residual_m
    text = c.read_text()
    assert text == kinematics_csv(art)
    assert "residual: max position" in text and "Rz(q_i + theta_offset_i)" in text
    rows = list(csv.DictReader(line for line in text.splitlines() if not line.startswith("#")))
    mdh = [r for r in rows if r["form"] == "mdh"]
    assert [r["joint"] for r in mdh] == list(robot.joint_names)
    assert float(mdh[2]["a_m"]) == art.mdh.joints[2].a_m
    assert float(mdh[1]["zero_offset_rad"]) == art.zero_offsets[1].offset_rad


def test_rxcomm_export_of_the_kinematics_yaml_is_the_csv_beside_it(tmp_path, calibrated):
    from typer.testing import CliRunner

    from rxcomm.cli import app

    _, _, art = calibrated
    y, c = write_kinematics(tmp_path / "mdh.yaml", art)
    out = tmp_path / "again.csv"
    r = CliRunner().invoke(app, ["export", str(y), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert out.read_text() == c.read_text()
