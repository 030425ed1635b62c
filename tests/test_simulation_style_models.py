"""A robot imported from a model written for simulation, the way others write them (issue 26: "we will
check this on MJCF models written by others"): tests/data/parallel_axes_arm.xml has the parallel-axis
class's kinematics (shoulder, elbow and first wrist axis parallel, a non-spherical wrist), joints named
like their bodies, position actuators, a keyframe with ctrl, and a `damping` that stabilises the
simulation (150 N·m·s/rad on a 120 N·m joint) rather than models friction. The UR5e of MuJoCo
Menagerie stopped the chain at each of these (docs/architecture.md §6.1, "imported robots")."""

from __future__ import annotations

import re
from pathlib import Path

import mujoco  # noqa: F401  (its first import starts a process: at collection, not in a unit test)
import numpy as np
import pytest
from typer.testing import CliRunner

from rxcomm.cli import app
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.model.dynamics import prior_parameters
from rxcomm.model.robot import load_robot
from rxcomm.schemas.acceptance import AcceptanceThresholds
from rxcomm.schemas.cell import Cell

ARM = Path(__file__).parent / "data" / "parallel_axes_arm.xml"


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("parallel") / "arm"
    r = CliRunner().invoke(app, ["import-robot", str(ARM), "-o", str(out)])
    assert r.exit_code == 0, r.output
    return out


def test_import_writes_what_make_commission_reads(arm):
    """A joint named like its link loads (Pinocchio refused the bare name as ambiguous); the directory
    holds a cell, acceptance thresholds and ISO 9283 paths, each marked assumed, so `make commission
    ROBOT=DIR` needs nothing written by hand."""
    robot = load_robot(arm)
    assert robot.model.frames[robot.flange_frame_id].name == "w3"
    cell = read_yaml_model(arm / "cell.yaml", Cell)
    assert cell.tracker.range_max_m > np.linalg.norm(cell.tracker.tracker_to_base.xyz_m) + robot.reach_m
    rows = read_yaml_model(arm / "acceptance.yaml", AcceptanceThresholds).criteria
    assert {r.criterion for r in rows} >= {"AP_p", "AT_p", "RP_l", "cycle_time"}
    assert all(r.max_ratio for r in rows if r.criterion != "RP_l")
    for name in ("cell.yaml", "acceptance.yaml"):
        assert (arm / name).read_text().startswith("# ASSUMED by `rxcomm import-robot`")
    assert sorted(p.name for p in (arm / "paths").iterdir()) == [
        "iso9283-circle-large.yaml",
        "iso9283-circle-small.yaml",
        "iso9283-line.yaml",
        "iso9283-rectangle.yaml",
    ]


def test_reimport_keeps_the_users_cell_and_paths(arm, tmp_path):
    """Nothing a user edited is lost: a second import rewrites the URDF and drives.yaml only."""
    import shutil

    again = tmp_path / "arm"
    shutil.copytree(arm, again)
    edited = (again / "cell.yaml").read_text() + "# edited by the cell's integrator\n"
    (again / "cell.yaml").write_text(edited)
    (again / "paths" / "iso9283-line.yaml").unlink()
    r = CliRunner().invoke(app, ["import-robot", str(ARM), "-o", str(again)])
    assert r.exit_code == 0, r.output
    assert (again / "cell.yaml").read_text() == edited
    assert not (again / "paths" / "iso9283-line.yaml").exists()
    assert "kept" in r.output and "cell.yaml" in r.output


def test_velocity_limits_follow_a_simulation_damping(arm):
    """No joint is given a speed its own viscous friction makes unreachable: at the velocity limit the
    damping needs at most half the peak torque (the assumed 3 rad/s would need 3.75 × the peak)."""
    robot = load_robot(arm)
    viscous = np.array([j.viscous_friction_nm_s_per_rad for j in robot.drives.joints])
    assert np.all(viscous * np.asarray(robot.v_max) <= 0.5 * np.asarray(robot.tau_max) + 1e-9)
    assert robot.v_max[0] == pytest.approx(0.5 * 120 / 150)
    assert "damping (150 N·m·s/rad)" in (arm / "drives.yaml").read_text()


def test_iso_paths_are_clear_of_the_wrist_singularity(arm):
    """The 27 points of the test cube can all be clear of singularities while a path between them
    crosses one; every written path is followed by the planners' path IK with σ_min ≥ 0.05, 10× the
    planners' margin (at 0.024 the line ended 2° from the wrist singularity, where the calibration
    turned J4 and J6 by 0.09 rad for the same TCP pose and `accept` refused the task as another)."""
    from rxcomm.planning.path_ik import solve_path_ik
    from rxcomm.planning.paths import load_path

    robot = load_robot(arm)
    for f in sorted((arm / "paths").iterdir()):
        spec, path = load_path(f, robot)
        jp = solve_path_ik(robot, path, spec.branch)
        assert jp.sigma_min.min() >= 0.05, f.name


def test_time_optimal_path_with_dominant_viscous_friction(arm, tmp_path):
    """toppra's viscous bound was the tangent at the velocity bound, which claimed half the friction
    there even at rest (here more than the peak): every path was uncontrollable. The plan now exists
    and its sampled torque stays within the limits."""
    out = tmp_path / "circle.mcap"
    path = arm / "paths" / "iso9283-circle-large.yaml"
    r = CliRunner().invoke(app, ["plan-cp", "--robot", str(arm), "--path", str(path), "-o", str(out)])
    assert r.exit_code == 0, r.output
    from rxcomm.io.yaml_io import read_yaml_artefact
    from rxcomm.schemas.trajectory import TrajectorySummary

    summary = read_yaml_artefact(out.with_suffix(".yaml"), TrajectorySummary).summary
    assert summary.max_limit_ratio <= 1.002


def test_moves_between_poses_are_paced_by_the_models_torque(arm, tmp_path):
    """A campaign's or an approach's move at a fraction of the velocity limits knows nothing of
    friction: with the 3 rad/s a drives.yaml may well state, at 50 % the damping alone takes this arm's
    shoulder past its peak. The paced move stays within 0.9 × every peak on the prior model, and is
    slower for it."""
    import shutil

    from rxcomm.execution.approach import move_trajectory
    from rxcomm.execution.plan import model_torque

    fast = tmp_path / "arm"
    shutil.copytree(arm, fast)
    urdf = fast / "parallel_axes_arm.urdf"
    urdf.write_text(re.sub(r'velocity="[0-9.e+-]+"', 'velocity="3"', urdf.read_text()))
    robot = load_robot(fast)
    params = prior_parameters(robot)
    q0, q1 = np.zeros(6), np.array([2.0, -1.0, 1.0, 0.5, 0.5, 0.5])
    tau_max = np.asarray(robot.tau_max)
    plain = move_trajectory(robot, q0, q1, robot.drives.cycle_s, 0.5)
    paced = move_trajectory(robot, q0, q1, robot.drives.cycle_s, 0.5, paced_by=params)
    ratio = lambda m: np.max(np.abs(model_torque(robot, params, m.q, m.qd, m.qdd)) / tau_max)  # noqa: E731
    assert ratio(plain) > 1.0 and ratio(paced) <= 0.9
    assert paced.t[-1] > plain.t[-1]
    assert np.allclose(paced.q[-1], q1) and np.allclose(paced.qd[-1], 0.0)


def test_the_mujoco_plant_drops_keyframes_and_sensors_with_the_actuators(arm, tmp_path):
    """The kept MJCF's keyframe holds a ctrl per actuator; with the actuators dropped MuJoCo refused
    the model ("keyframe 0: invalid ctrl size") and the embedded cell never started. Its collision
    mesh's file is absent: the plant drops that geom as import-robot did (MuJoCo Menagerie's M1013
    without its assets stopped here: "Error opening file")."""
    from rxcomm.cell.mujoco_model import build_mujoco_model
    from rxcomm.cell.truth import load_truth

    truth = tmp_path / "truth.yaml"
    r = CliRunner().invoke(app, ["truth", "--robot", str(arm), "--seed", "3", "-o", str(truth)])
    assert r.exit_code == 0, r.output
    built = build_mujoco_model(load_truth(truth))
    assert built.model.nkey == 0 and built.model.nu == 0 and built.model.nmesh == 0


def test_excitation_speed_constraint_matches_finite_differences(arm):
    """g_j = mean q̇_j² / v_j² − 1 and its gradient (the SLSQP constraint that keeps every joint moving)."""
    from rxcomm.identification.excitation_problem import ExcitationProblem
    from rxcomm.schemas.excitation import ExcitationSettings

    prob = ExcitationProblem(load_robot(arm), None, ExcitationSettings())
    x = prob.random_feasible(np.random.default_rng(0))
    fun, jac = prob._speed_constraints()
    step = 1e-6 * np.eye(len(x))
    numeric = np.array([(fun(x + e) - fun(x - e)) / 2e-6 for e in step]).T
    assert np.abs(jac(x) - numeric).max() <= 1e-6 * np.abs(numeric).max()
    _, qd, _ = prob.states(x, prob.t_obj)
    v_min = np.minimum(0.15, 0.25 * prob.v_half)
    assert np.allclose(fun(x), np.mean(qd**2, axis=0) / v_min**2 - 1.0)


@pytest.mark.slow
def test_every_joint_of_the_excitation_moves(arm):
    """cond(W) on unit columns cannot see a joint that barely moves: with this arm's friction-dominated
    shoulder the optimum kept it under identify's 0.05 rad/s row threshold; the design now keeps every
    joint's RMS speed at min(0.15 rad/s, ¼ of its limit) or above."""
    from rxcomm.identification.excitation import design_excitation
    from rxcomm.schemas.excitation import ExcitationSettings

    robot = load_robot(arm)
    region = read_yaml_model(arm / "cell.yaml", Cell).allowed_region
    design = design_excitation(robot, region, ExcitationSettings(starts=2), workers=1)
    t = np.linspace(0.0, design.trajectory.period_s, 2001)[:-1]
    _, qd, _ = design.trajectory.evaluate(t)
    rms = np.sqrt(np.mean(qd**2, axis=0))
    assert np.all(rms >= 0.99 * np.minimum(0.15, 0.25 * np.asarray(robot.v_max) * 0.95)), rms
