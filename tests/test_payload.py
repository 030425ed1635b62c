"""A payload on the flange (issue 29): the augmented dynamics against an independent Newton–Euler
reference, its identification on synthetic torques, refusals of bad payload files, and (slow) the
simulated cell's hidden payload recovered by `identify-payload` on both samples."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.cell.truth import load_truth
from rxcomm.cli import app
from rxcomm.errors import InputError
from rxcomm.identification.logs import JointLog
from rxcomm.identification.payload import identify_payload
from rxcomm.identification.settings import IdentifySettings
from rxcomm.model.dynamics import RobotDynamics, prior_parameters, random_states
from rxcomm.model.payload import FlangeInertia, flange_inertia, payload_inertial, with_payload
from rxcomm.schemas.payload import inertia_matrix

from .conftest import SAMPLES
from .runs import Q0, cosine_plan, save_plan

LOAD = FlangeInertia(
    5.0, np.array([0.015, -0.010, 0.100]), inertia_matrix((0.0125, 0.001, 0.011, 0.0, 0.0, 0.007))
)


def newton_euler_payload_torque(robot, load: FlangeInertia, q, qd, qdd) -> np.ndarray:
    """τ the load alone needs, from its own Newton–Euler equations at its centre of mass and the flange
    Jacobian (Pinocchio only for the flange's kinematics): τ = Jᵀ·(F, M_flange)."""
    m, d = robot.model, robot.create_data()
    fid = robot.flange_frame_id
    pin.forwardKinematics(m, d, q, qd, qdd)
    pin.updateFramePlacements(m, d)
    world = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    o_m_f = d.oMf[fid]
    v = pin.getFrameVelocity(m, d, fid, world)
    a = pin.getFrameClassicalAcceleration(m, d, fid, world)
    w, alpha, a_o = v.angular, a.angular, a.linear
    r = o_m_f.rotation @ load.com_m
    a_c = a_o + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
    force = load.mass_kg * (a_c - m.gravity.linear)
    i_w = o_m_f.rotation @ load.inertia_com_kgm2 @ o_m_f.rotation.T
    moment = i_w @ alpha + np.cross(w, i_w @ w) + np.cross(r, force)
    jac = pin.computeFrameJacobian(m, d, q, fid, world)
    return jac.T @ np.concatenate([force, moment])


@pytest.mark.parametrize("name", ["rx130l", "m900"])
def test_payload_torque_matches_newton_euler_of_the_load(name):
    robot = pytest.importorskip("rxcomm.model.robot").load_robot(SAMPLES / name)
    params = prior_parameters(robot)
    q, qd, qdd = random_states(robot, 6, seed=3)
    bare = RobotDynamics(robot, params).inverse_dynamics(q, qd, qdd)
    loaded = RobotDynamics(robot, with_payload(robot, params, LOAD)).inverse_dynamics(q, qd, qdd)
    for i in range(len(q)):
        ref = newton_euler_payload_torque(robot, LOAD, q[i], qd[i], qdd[i])
        assert np.abs(ref).max() > 1.0  # the load matters at these states
        np.testing.assert_allclose(loaded[i] - bare[i], ref, atol=1e-8 * np.abs(ref).max() + 1e-9)
    # a wrong centre of mass is seen: the reference is not trivially met
    moved = FlangeInertia(LOAD.mass_kg, LOAD.com_m + [0.0, 0.0, 0.01], LOAD.inertia_com_kgm2)
    assert (
        np.abs(newton_euler_payload_torque(robot, moved, q[0], qd[0], qdd[0]) - (loaded[0] - bare[0])).max()
        > 0.1
    )


def test_flange_inertia_round_trips(rx130l):
    back = flange_inertia(rx130l, payload_inertial(rx130l, LOAD))
    assert back.mass_kg == pytest.approx(LOAD.mass_kg)
    np.testing.assert_allclose(back.com_m, LOAD.com_m, atol=1e-12)
    np.testing.assert_allclose(back.inertia_com_kgm2, LOAD.inertia_com_kgm2, atol=1e-12)


def test_payload_is_identified_from_synthetic_torques_with_the_model_fixed(rx130l):
    """Torques of the loaded arm + noise; the bare model fixed: mass, centre of mass back, σ honest."""
    params = prior_parameters(rx130l)
    dt = rx130l.drives.cycle_s
    t = np.arange(0.0, 12.0, dt)
    w = np.array([0.9, 0.7, 1.1, 1.7, 1.3, 2.1])
    q = Q0 + 0.5 * np.sin(np.outer(t, w)) * [0.8, 0.4, 0.4, 1.2, 1.0, 1.5]
    qd = np.gradient(q, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    tau = RobotDynamics(rx130l, with_payload(rx130l, params, LOAD)).inverse_dynamics(q, qd, qdd)
    rng = np.random.default_rng(5)
    tau = tau + rng.standard_normal(tau.shape) * 0.2
    res = identify_payload(rx130l, params, JointLog(t, q, tau, "synthetic"), IdentifySettings(cutoff_hz=10.0))
    assert res.load.mass_kg == pytest.approx(LOAD.mass_kg, rel=5e-3)
    np.testing.assert_allclose(res.load.com_m, LOAD.com_m, atol=1e-3)
    assert 0 < res.mass_std_kg < 0.05
    assert abs(res.load.mass_kg - LOAD.mass_kg) < 5 * res.mass_std_kg + 1e-3


def test_a_bad_truth_payload_names_file_field_and_reason(tmp_path):
    bad = tmp_path / "payload.yaml"
    bad.write_text(
        "kind: rxcomm/CellPayload\nschema_version: 1\n"
        "payload: {mass_kg: 5.0, com_m: [0, 0, 0.1], inertia_com_kgm2: [0.01, 0, 0.01, 0, 0, 0.05]}\n"
    )
    with pytest.raises(InputError) as e:
        load_truth(SAMPLES / "rx130l" / "truth.yaml", payload_path=bad)
    assert str(e.value.file) == str(bad) and "inertia_com_kgm2" in str(e.value) and "triangle" in str(e.value)
    bad.write_text(
        "kind: rxcomm/CellPayload\nschema_version: 1\npayload: {mass_kg: -1, com_m: [0, 0, 0.1]}\n"
    )
    with pytest.raises(InputError) as e:
        load_truth(SAMPLES / "rx130l" / "truth.yaml", payload_path=bad)
    assert "mass_kg" in str(e.value)
    ok = tmp_path / "ok.yaml"
    ok.write_text(
        "kind: rxcomm/CellPayload\nschema_version: 1\npayload: {mass_kg: 5.0, com_m: [0.015, -0.01, 0.1]}\n"
    )
    truth = load_truth(SAMPLES / "rx130l" / "truth.yaml", payload_path=ok)
    bare = load_truth(SAMPLES / "rx130l" / "truth.yaml")
    assert truth.params.inertial[-1][0] == pytest.approx(bare.params.inertial[-1][0] + 5.0)


def _one_line_exit_2(res, *named: str) -> None:
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output
    lines = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.output
    for name in named:
        assert name in lines[0], f"{name!r} not in {lines[0]!r}"


def _payload_artefact(robot, path: Path) -> Path:
    """A valid payload.yaml of LOAD on `robot` (as identify-payload writes it)."""
    from rxcomm.identification.payload_artefact import controller_form
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.schemas.payload import Payload, PayloadFit

    summary = {"mass_kg": 5.0, "com_m": LOAD.com_m.tolist(), "validation_rms_without_nm": None}
    summary |= {"validation_rms_with_nm": None, "seconds": 0.0}
    art = Payload(
        **Payload.envelope({}, {}, summary),
        robot=robot.name,
        flange_frame=robot.model.frames[robot.flange_frame_id].name,
        mass_kg=LOAD.mass_kg,
        mass_std_kg=0.01,
        com_m=tuple(LOAD.com_m),
        com_std_m=(1e-4, 1e-4, 1e-4),
        inertia_com_kgm2=LOAD.inertia6,
        inertia_com_std_kgm2=(1e-3,) * 6,
        inertial_parameters=payload_inertial(robot, LOAD).tolist(),
        fit=PayloadFit(
            log="x.mcap", rows=1000, cond=5.0, residual_rms_nm=[0.1] * 6, noise_weights_nm=[0.1] * 6
        ),
        validation=None,
        controller=controller_form(LOAD),
    )
    write_yaml_artefact(path, art)
    return path


@pytest.mark.slow
def test_the_cli_refuses_a_bad_payload_file_with_exit_2(tmp_path, rx130l):
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, np.full(6, 0.1), 0.5))
    good = _payload_artefact(rx130l, tmp_path / "payload.yaml")
    bad = tmp_path / "bad-payload.yaml"
    text = yaml.safe_load(good.read_text())
    bad.write_text(yaml.safe_dump(text | {"mass_kg": "heavy"}))
    runner = CliRunner()
    r = str(SAMPLES / "rx130l")
    out = ["-o", str(tmp_path / "c.mcap")]
    res = runner.invoke(app, ["plan-cycles", str(plan), "--robot", r, "--payload", str(good), *out])
    assert res.exit_code == 0, res.output  # the artefact as written is taken
    bad.write_text(yaml.safe_dump(text | {"robot": "another-arm"}))
    res = runner.invoke(app, ["plan-cycles", str(plan), "--robot", r, "--payload", str(bad), *out])
    _one_line_exit_2(res, "bad-payload.yaml", "robot", "another-arm")
    bad.write_text(yaml.safe_dump(text | {"mass_kg": "heavy"}))
    res = runner.invoke(
        app, ["plan-cycles", str(plan), "--robot", r, "--payload", str(bad), "-o", str(tmp_path / "c.mcap")]
    )
    _one_line_exit_2(res, "bad-payload.yaml", "mass_kg")
    truth_bad = tmp_path / "truth-payload.yaml"
    truth_bad.write_text(
        "kind: rxcomm/CellPayload\nschema_version: 1\npayload: {mass_kg: 0, com_m: [0, 0, 0]}\n"
    )
    res = runner.invoke(
        app,
        ["run", str(plan), "--robot", r, "--truth-payload", str(truth_bad), "-o", str(tmp_path / "l.mcap")],
    )
    _one_line_exit_2(res, "truth-payload.yaml", "mass_kg")
    res = runner.invoke(
        app,
        ["run", str(plan), "--robot", r, "--gateway", "127.0.0.1:1", "--truth-payload", str(truth_bad)]
        + ["-o", str(tmp_path / "l.mcap")],
    )
    _one_line_exit_2(res, "truth-payload")


# ------------------------------------------------------------------------------------------- slow: the cell


def _excitation(robot, robot_dir: Path, seed: int, path: Path) -> Path:
    from rxcomm.identification.excitation_problem import ExcitationProblem
    from rxcomm.identification.excitation_trajectory import sample_trajectory
    from rxcomm.io.yaml_io import read_yaml_model
    from rxcomm.model.base_parameters import base_parameters
    from rxcomm.schemas.cell import Cell
    from rxcomm.schemas.excitation import ExcitationSettings

    cell = read_yaml_model(robot_dir / "cell.yaml", Cell)
    prob = ExcitationProblem(
        robot, cell.allowed_region, ExcitationSettings(check_samples=400), base_parameters(robot)
    )
    return save_plan(
        path, sample_trajectory(robot, prob.trajectory(prob.random_feasible(np.random.default_rng(seed))))
    )


@pytest.mark.slow
@pytest.mark.socket
@pytest.mark.parametrize("name", ["rx130l", "m900"])
def test_identify_payload_recovers_the_cells_hidden_payload(tmp_path, name):
    """The cell carries the sample's truth-payload.yaml; the robot is identified on the same cell without
    it (`identify`), then `identify-payload` recovers the load from a run with it: mass within 2 %, centre
    of mass within 2 mm, and the validation on another motion improves with it."""
    from rxcomm.io.yaml_io import read_yaml_model
    from rxcomm.model.robot import load_robot
    from rxcomm.schemas.payload import CellPayload
    from rxcomm.stages import identify, identify_payload, run

    robot_dir = SAMPLES / name
    robot = load_robot(robot_dir)
    truth_payload = robot_dir / "truth-payload.yaml"
    hidden = read_yaml_model(truth_payload, CellPayload).payload  # the test scores against the truth
    exc = _excitation(robot, robot_dir, 11, tmp_path / "exc.mcap")
    val = _excitation(robot, robot_dir, 12, tmp_path / "val.mcap")
    common = dict(approach=True, interpolation_ratio=1, show_progress=False)
    run.execute(exc, robot_dir, tmp_path / "bare.mcap", **common)
    run.execute(exc, robot_dir, tmp_path / "loaded.mcap", truth_payload=truth_payload, **common)
    run.execute(val, robot_dir, tmp_path / "loaded-val.mcap", truth_payload=truth_payload, **common)
    identify.run(
        robot_dir,
        tmp_path / "bare.mcap",
        tmp_path / "dynamics.yaml",
        settings={"cutoff_hz": 10.0, "max_cond": 1e5},
    )
    art = identify_payload.run(
        robot_dir,
        tmp_path / "loaded.mcap",
        tmp_path / "dynamics.yaml",
        tmp_path / "payload.yaml",
        validate=tmp_path / "loaded-val.mcap",
    )
    mass_err = abs(art.mass_kg - hidden.mass_kg) / hidden.mass_kg
    com_err = np.linalg.norm(np.array(art.com_m) - hidden.com_m)
    com_mm = np.round(np.array(art.com_m) * 1e3, 2)
    print(
        f"{name}: mass {art.mass_kg:.4f} ± {art.mass_std_kg:.4f} kg (truth {hidden.mass_kg}), "
        f"CoM {com_mm} mm (truth {np.array(hidden.com_m) * 1e3}), error {com_err * 1e3:.2f} mm; validation "
        f"RMS {art.validation.total_rms_without_nm:.3g} → {art.validation.total_rms_with_nm:.3g} N·m"
    )
    assert mass_err < 0.02
    assert com_err < 0.002
    assert art.validation.total_rms_with_nm < 0.5 * art.validation.total_rms_without_nm


def test_the_own_plant_carries_the_truth_payload_on_the_last_link():
    from rxcomm.cell.sim import simulated_cell

    truth, load = SAMPLES / "rx130l" / "truth.yaml", SAMPLES / "rx130l" / "truth-payload.yaml"
    own, own0 = simulated_cell(truth, payload_path=load), simulated_cell(truth)
    assert own.plant.model.inertias[6].mass == pytest.approx(own0.plant.model.inertias[6].mass + 5.0)


@pytest.mark.process
def test_the_mujoco_plant_carries_the_truth_payload():
    pytest.importorskip("mujoco")
    from rxcomm.cell.sim import simulated_cell

    truth, load = SAMPLES / "rx130l" / "truth.yaml", SAMPLES / "rx130l" / "truth-payload.yaml"
    muj, muj0 = (
        simulated_cell(truth, plant="mujoco", payload_path=load),
        simulated_cell(truth, plant="mujoco"),
    )
    mass, mass0 = muj.plant.built.model.body_mass, muj0.plant.built.model.body_mass
    assert float(mass.sum() - mass0.sum()) == pytest.approx(5.0)


def test_controller_forms_rebuild_the_inertia():
    """Principal moments and axes give back I_c; the flange-origin inertia is I_c + m(|c|²E − ccᵀ)."""
    from rxcomm.identification.payload_artefact import controller_form

    form = controller_form(LOAD)
    w, x, y, z = form.principal_axes_wxyz
    rot = pin.Quaternion(w, x, y, z).toRotationMatrix()
    np.testing.assert_allclose(
        rot @ np.diag(form.principal_moments_kgm2) @ rot.T, LOAD.inertia_com_kgm2, atol=1e-12
    )
    assert np.linalg.det(rot) == pytest.approx(1.0)
    m, (cx, cy, cz) = LOAD.mass_kg, LOAD.com_m
    assert form.inertia_flange_kgm2["xz"] == pytest.approx(LOAD.inertia_com_kgm2[0, 2] - m * cx * cz)
    assert form.inertia_flange_kgm2["zz"] == pytest.approx(
        LOAD.inertia_com_kgm2[2, 2] + m * (cx * cx + cy * cy)
    )
    assert form.com_mm == pytest.approx((15.0, -10.0, 100.0))
    assert form.physically_consistent


@pytest.mark.parametrize("name", ["rx130l", "m900"])
def test_an_identified_inertia_that_is_no_bodys_is_still_fed_forward(name):
    """A light load's moments identified slightly negative (within σ; RX130L 0.5 kg: Ixx −0.0004 ±
    0.0004 kg·m²) are taken as estimated: the parameters are linear in the inertia, so the load equals
    a valid body's plus the difference of the tensors (Pinocchio's Inertia would refuse it)."""
    robot = pytest.importorskip("rxcomm.model.robot").load_robot(SAMPLES / name)
    valid = inertia_matrix((0.0004, 0.0, 0.0004, 0.0, 0.0, 0.0006))
    odd = inertia_matrix((-0.0004, 0.0005, -0.0004, 0.0, 0.0, 0.0006))
    com = np.array([0.005, -0.004, 0.04])
    p_odd = payload_inertial(robot, FlangeInertia(0.5, com, odd))
    p_valid = payload_inertial(robot, FlangeInertia(0.5, com, valid))
    np.testing.assert_allclose(p_odd[:4], p_valid[:4], atol=1e-15)
    from rxcomm.model.payload import flange_placement

    r = flange_placement(robot).rotation
    d = r @ (odd - valid) @ r.T
    np.testing.assert_allclose(
        p_odd[4:] - p_valid[4:], [d[0, 0], d[0, 1], d[1, 1], d[0, 2], d[1, 2], d[2, 2]], atol=1e-15
    )
    params = prior_parameters(robot)
    q, qd, qdd = random_states(robot, 2, seed=1)
    tau = RobotDynamics(robot, with_payload(robot, params, FlangeInertia(0.5, com, odd))).inverse_dynamics(
        q, qd, qdd
    )
    assert np.all(np.isfinite(tau))
