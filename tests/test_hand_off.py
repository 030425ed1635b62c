"""Issue 31, the hand-off: every export format read back by an independent reader with its parity
figure, and plans written elsewhere (CSV, ROS 2 JointTrajectory YAML) run back through `run`."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import yaml
from typer.testing import CliRunner

from rxcomm.calibration.parity import HOLD_M, compare, mdh_fk, origins_fk, parity_poses, urdf_fk
from rxcomm.cli import app
from rxcomm.execution.log_grid import joint_grid_steps
from rxcomm.io.csv_export import read_csv_table
from rxcomm.io.ros2_bag import read_bag
from rxcomm.io.ros2_trajectory import read_ros2_trajectory
from rxcomm.io.run_log import read_run_log
from rxcomm.io.trajectory import Trajectory, save_trajectory_mcap
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.model.geometric_errors import ErrorModel, parameter_names
from rxcomm.schemas.trajectory import TrajectorySummary
from rxcomm.stages import run as run_stage

from .artefacts import synthetic_calibration
from .test_foxglove_log import run_log  # noqa: F401 - a run log of the embedded cell
from .test_run import DQ, Q0, ROBOT_DIR, gw, start_cell

runner = CliRunner()
# A calibration that tilts axis 3 against its parallel axis 2 (what plain MDH cannot follow), moves
# the base and the tool and shifts a zero: a few tenths of a millimetre at the TCP.
ERRORS = {
    "base.tz": 1.2e-3,
    "base.rx": 3e-4,
    "joint_2.rz": 5e-4,
    "joint_3.rx": 4e-4,
    "joint_3.tx": 6e-4,
    "joint_5.ry": -7e-4,
    "tool.tx": 2e-4,
    "tool.rz": 1e-3,
}


@pytest.fixture(scope="module")
def exports(tmp_path_factory, rx130l):
    tmp = tmp_path_factory.mktemp("handoff")
    cal = tmp / "calibration.yaml"
    write_yaml_artefact(cal, synthetic_calibration(rx130l, ERRORS))
    r = runner.invoke(
        app, ["export", str(cal), "--robot", str(ROBOT_DIR), "--format", "all", "-o", str(tmp / "exports")]
    )
    assert r.exit_code == 0, r.output
    errors = ErrorModel.from_mapping(rx130l, ERRORS)
    return tmp / "exports", r.output, errors.apply(rx130l)


def _parity(out, fmt):
    rows = yaml.safe_load((out / "parity.yaml").read_text())["exports"]
    return next(r for r in rows if r["format"] == fmt)


def test_urdf_export_read_by_pinocchio_and_urdfdom_holds_the_calibration(exports, rx130l):
    out, console, calibrated = exports
    text = (out / "calibration.urdf").read_text()
    qs = parity_poses(rx130l)
    # a second independent reader: Pinocchio's own URDF parser on the file, its TCP link's FK
    model = pin.buildModelFromXML(text)
    data, fid = model.createData(), model.getFrameId("tcp")
    ref = calibrated
    t = np.stack([(pin.framesForwardKinematics(model, data, q), data.oMf[fid].homogeneous)[1] for q in qs])
    assert compare("pinocchio", rx130l, ref, qs, t).max_position_m < 1e-9
    p = _parity(out, "urdf")["parity"]
    assert p["n_poses"] >= 200 and p["max_position_m"] <= HOLD_M and p["holds_1um"]
    assert "parity" in console and "calibration.urdf" in console
    # the check can fail: joint_3's origin 10 µm off is seen
    bad = text.replace('<joint name="joint_3"', '<joint name="joint_3"', 1)
    j3 = bad.index('<joint name="joint_3"')
    o = bad.index('xyz="', j3) + 5
    x = bad[o : bad.index(" ", o)]
    bad = bad[:o] + repr(float(x) + 1e-5) + bad[o + len(x) :]
    moved = compare("urdfdom", rx130l, ref, qs, urdf_fk(bad, list(rx130l.joint_names), "tcp", qs))
    assert 5e-6 < moved.max_position_m < 2e-5 and not moved.holds


def test_hayati_and_origin_tables_hold_plain_mdh_states_its_residual(exports, rx130l):
    out, console, calibrated = exports
    qs = parity_poses(rx130l)
    hay = yaml.safe_load((out / "calibration.mdh-hayati.yaml").read_text())
    plain = yaml.safe_load((out / "calibration.mdh.yaml").read_text())
    origins = yaml.safe_load((out / "calibration.joint-origins.yaml").read_text())
    assert "Rz(yaw)" in hay["convention"] and "Rz(yaw)" in origins["convention"]  # angle order written
    assert compare("t", rx130l, calibrated, qs, mdh_fk(hay, qs)).max_position_m <= HOLD_M
    assert compare("t", rx130l, calibrated, qs, origins_fk(origins, qs)).max_position_m <= HOLD_M
    assert any(abs(j["beta_rad"]) > 1e-5 for j in hay["joints"])  # the tilt went into a β
    resid = compare("t", rx130l, calibrated, qs, mdh_fk(plain, qs))
    assert resid.max_position_m > 10e-6  # the tilt costs plain MDH (here ≈ 0.3 mm)
    assert plain["parity"]["max_position_m"] == pytest.approx(resid.max_position_m, rel=1e-9)
    assert not plain["parity"]["holds_1um"] and "mdh-hayati" in plain["note"]
    assert "mdh-hayati or urdf" in console
    for fmt in ("mdh-hayati", "joint-origins"):
        assert _parity(out, fmt)["parity"]["holds_1um"], fmt


def _named_plan(path, rx130l, dt=0.002, scale=0.25):
    duration = 0.4
    t = np.arange(int(round(duration / dt)) + 1) * dt
    w = np.pi / duration
    s, sd, sdd = 0.5 - 0.5 * np.cos(w * t), 0.5 * w * np.sin(w * t), 0.5 * w * w * np.cos(w * t)
    dq = scale * DQ
    tau = np.outer(sdd, 10 * dq) + np.array([0.0, 120.0, 35.0, 1.0, 4.0, 0.2])
    traj = Trajectory(t, Q0 + np.outer(s, dq), np.outer(sd, dq), np.outer(sdd, dq), tau)
    summary = {
        "duration_s": duration,
        "solve_seconds": 0.0,
        "max_limit_ratio": 0.5,
        "active_fraction": 0.0,
        "q_start": traj.q[0].tolist(),
        "q_goal": traj.q[-1].tolist(),
    }
    save_trajectory_mcap(path, traj, TrajectorySummary.envelope({}, {}, summary), rx130l.joint_names)
    return path, traj


@pytest.mark.slow
def test_trajectory_exports_reread_exactly_and_the_bag_decodes(tmp_path, rx130l):
    plan, traj = _named_plan(tmp_path / "plan.mcap", rx130l)
    r = runner.invoke(app, ["export", str(plan), "--format", "all", "-o", str(tmp_path / "x")])
    assert r.exit_code == 0, r.output
    names = list(rx130l.joint_names)
    back, got = read_ros2_trajectory(tmp_path / "x" / "plan.ros2-trajectory.yaml")
    assert got == names and np.array_equal(back.q, traj.q) and np.array_equal(back.tau_ff, traj.tau_ff)
    assert np.max(np.abs(back.t - traj.t)) <= 0.5e-9
    _, cols = read_csv_table(tmp_path / "x" / "plan.csv")
    assert "q_joint_1_rad" in cols and "tau_ff_joint_6_Nm" in cols
    assert np.array_equal(cols["qd_joint_3_rad_s"], traj.qd[:, 2])
    msgs = [m for topic, _, m in read_bag(tmp_path / "x" / "plan.ros2.mcap") if topic == "/joint_states"]
    assert len(msgs) == traj.n and all(list(m.name) == names for m in msgs)
    assert np.array_equal(np.array([list(m.effort) for m in msgs]), traj.tau_ff)
    rows = yaml.safe_load((tmp_path / "x" / "parity.yaml").read_text())["exports"]
    assert {r["format"] for r in rows} == {"csv", "ros2-trajectory", "ros2-bag"}
    assert all(r["re-read"]["max_value_difference"] == 0.0 for r in rows)


def _run(plan, out, srv):
    return run_stage.execute(
        plan, ROBOT_DIR, out, gateway=gw(srv), interpolation_ratio=1, show_progress=False
    )


@pytest.mark.slow
def test_joint_trajectory_runs_and_its_log_reproduces_the_plan(tmp_path, rx130l):
    plan, traj = _named_plan(tmp_path / "plan.mcap", rx130l)
    assert runner.invoke(app, ["export", str(plan), "--format", "ros2-trajectory"]).exit_code == 0
    srv = start_cell(rx130l)
    try:
        _run(tmp_path / "plan.ros2-trajectory.yaml", tmp_path / "yaml-log.mcap", srv)
    finally:
        srv.stop()
    log = read_run_log(tmp_path / "yaml-log.mcap")
    assert log.joints.constants["joint_names"] == list(rx130l.joint_names)
    q = log.joints.q_demand
    step = round(0.002 / rx130l.drives.cycle_s)  # the plan's samples fall on every 5th drive cycle
    k = np.arange(traj.n) * step
    assert q.shape[0] >= k[-1] + 1
    # the plan's own samples, through YAML and run; run logs store float32 on a 2^-21 rad grid
    # (docs/logs.md, execution/log_grid.py): half a grid step and one float32 ulp
    half_step = joint_grid_steps()["q_demand"] / 2
    assert np.all(np.abs(q[k] - traj.q) <= half_step + np.spacing(np.abs(traj.q).astype(np.float32)) + 1e-12)


@pytest.mark.slow
def test_hand_edited_csv_runs_and_one_beyond_a_limit_is_refused_naming_the_row(tmp_path, rx130l):
    plan, traj = _named_plan(tmp_path / "plan.mcap", rx130l)
    assert runner.invoke(app, ["export", str(plan)]).exit_code == 0
    lines = (tmp_path / "plan.csv").read_text().splitlines()
    first = next(i for i, ln in enumerate(lines) if ln.startswith("t_s"))
    header = lines[first].split(",")
    col = header.index("q_joint_1_rad")

    def edited(row, value):  # row: 1 = the first data row
        out = list(lines)
        cells = out[first + row].split(",")
        cells[col] = repr(float(value))
        out[first + row] = ",".join(cells)
        return "\n".join(out) + "\n"

    moved = tmp_path / "moved.csv"
    moved.write_text(edited(101, traj.q[100, 0] + 2e-4))  # one sample 0.2 mrad aside
    srv = start_cell(rx130l)
    try:
        _run(moved, tmp_path / "moved-log.mcap", srv)
    finally:
        srv.stop()
    q = read_run_log(tmp_path / "moved-log.mcap").joints.q_demand
    # the moved sample, as sent (the log's float32 grid: 2.4e-7 rad, one ulp at |q| <= 4 rad 4.8e-7)
    assert q[500, 0] - traj.q[100, 0] == pytest.approx(2e-4, abs=5e-7)
    beyond = tmp_path / "beyond.csv"
    beyond.write_text(edited(101, float(rx130l.q_max[0]) + 0.1))
    r = runner.invoke(
        app,
        [
            "run",
            str(beyond),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:9",
            "-o",
            str(tmp_path / "b.mcap"),
        ],
    )
    assert r.exit_code == 5, r.output
    assert "row 101" in r.output and "joint_1" in r.output and "beyond.csv" in r.output


@pytest.mark.socket  # the run_log fixture runs a plan on a served cell
def test_run_log_bag_decodes_message_by_message_with_the_log_s_names_and_stamps(run_log, tmp_path, rx130l):  # noqa: F811
    from mcap.reader import make_reader

    path, _ = run_log
    cal = tmp_path / "calibration.yaml"
    write_yaml_artefact(cal, synthetic_calibration(rx130l, ERRORS, names=list(parameter_names(rx130l))))
    out = tmp_path / "log.ros2.mcap"
    args = ["export", str(path), "--format", "ros2-bag", "--calibration", str(cal), "--robot", str(ROBOT_DIR)]
    r = runner.invoke(app, [*args, "-o", str(out)])
    assert r.exit_code == 0, r.output
    with open(path, "rb") as f:  # the log's own per-sample messages and their log times
        stamps = [m.log_time for _, _, m in make_reader(f).iter_messages(topics=["/run/joints"])]
    log = read_run_log(path)
    msgs = read_bag(out)
    states = [(ns, m) for topic, ns, m in msgs if topic == "/joint_states"]
    assert len(states) == len(stamps) == len(log.joints)
    assert all(list(m.name) == list(rx130l.joint_names) for _, m in states)
    assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in states] == stamps
    assert [ns for ns, _ in states] == stamps
    assert np.array_equal(np.array([list(m.position) for _, m in states]), log.joints.q_actual)
    demand = [m for topic, _, m in msgs if topic == "/joint_states_demand"]
    assert np.array_equal(np.array([list(m.effort) for m in demand]), log.joints.tau_ff)
    (tf,) = [m for topic, _, m in msgs if topic == "/tf_static"]
    assert tf.transforms[0].header.frame_id == "base_link" and tf.transforms[0].child_frame_id == "tracker"


def test_a_plan_carries_its_3d_view_for_foxglove(tmp_path, rx130l):
    import json

    from mcap.reader import make_reader

    from rxcomm.execution.plan_views import PLAN_TCP_TOPIC, PLAN_TF_TOPIC, plan_views
    from rxcomm.io.trajectory import load_trajectory_mcap
    from rxcomm.model.kinematics import tcp_pose

    _, traj = _named_plan(tmp_path / "bare.mcap", rx130l)
    env = TrajectorySummary.envelope({}, {}, {"duration_s": 0.4, "solve_seconds": 0.0, "max_limit_ratio": 0.5,
                                             "active_fraction": 0.0, "q_start": traj.q[0].tolist(),
                                             "q_goal": traj.q[-1].tolist()})  # fmt: skip
    path = tmp_path / "plan.mcap"
    save_trajectory_mcap(path, traj, env, rx130l.joint_names, plan_views(rx130l))
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        schemas = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        tf = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[PLAN_TF_TOPIC])]
        tcp = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=[PLAN_TCP_TOPIC])]
        urdf = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/robot_description"])]
    assert (
        schemas[PLAN_TF_TOPIC] == "foxglove.FrameTransforms"
        and schemas[PLAN_TCP_TOPIC] == "foxglove.PoseInFrame"
    )
    assert len(tf) == len(tcp) == 21  # 0.4 s at 50 Hz, and the last sample
    assert {t["child_frame_id"] for t in tf[0]["transforms"]} >= {"link_1", "link_6", "tcp"}
    assert "<robot" in urdf[0]["data"]
    p, _ = tcp_pose(rx130l, traj.q[-1])
    last = tcp[-1]["pose"]["position"]
    assert np.allclose([last["x"], last["y"], last["z"]], p, atol=1e-12)  # the planned TCP, where FK puts it
    back, _ = load_trajectory_mcap(path)  # the trajectory's readers skip the view channels
    assert np.array_equal(back.q, traj.q) and set(back.extra) == set()


# A UR5e's joint origins as ur_description chains them (every axis z): a robot whose joints match the UR
# driver's gets its calibration in the driver's kinematics.yaml layout too.
UR5E = {
    "shoulder_pan_joint": ("0 0 0.1625", "0 0 0"),
    "shoulder_lift_joint": ("0 0 0", "1.5707963267948966 0 0"),
    "elbow_joint": ("-0.425 0 0", "0 0 0"),
    "wrist_1_joint": ("-0.3922 0 0.1333", "0 0 0"),
    "wrist_2_joint": ("0 -0.0997 0", "1.5707963267948966 0 0"),
    "wrist_3_joint": ("0 0.0996 0", "1.5707963267948966 3.141592653589793 3.141592653589793"),
}


def _ur_robot(tmp_path):
    """The RX130L sample with its joints renamed and re-chained as a UR5e's (links and drives kept)."""
    import re

    from rxcomm.model.robot import load_robot

    d = tmp_path / "ur"
    d.mkdir()
    urdf = (ROBOT_DIR / "rx130l.urdf").read_text()
    drives = (ROBOT_DIR / "drives.yaml").read_text()
    for k, (name, (xyz, rpy)) in enumerate(UR5E.items(), start=1):
        i = urdf.index(f'<joint name="joint_{k}"')
        j = urdf.index("</joint>", i)
        body = re.sub(r"<origin [^>]*/>", f'<origin xyz="{xyz}" rpy="{rpy}"/>', urdf[i:j])
        body = re.sub(r"<axis [^>]*/>", '<axis xyz="0 0 1"/>', body).replace(f"joint_{k}", name)
        urdf = urdf[:i] + body + urdf[j:]
        drives = drives.replace(f"name: joint_{k},", f"name: {name},").replace(
            f"joint: joint_{k},", f"joint: {name},"
        )
    (d / "rx130l.urdf").write_text(urdf)
    (d / "drives.yaml").write_text(drives)
    return d, load_robot(d)


def test_a_ur_arm_s_calibration_is_also_in_the_ur_driver_s_kinematics_yaml_layout(tmp_path):
    from rxcomm.calibration.controller_files import UR_JOINTS, write_controller_file
    from rxcomm.calibration.parity import origin

    robot_dir, ur = _ur_robot(tmp_path)
    errors = {
        "shoulder_lift_joint.rx": 3e-4,
        "elbow_joint.tx": 5e-4,
        "base.tz": 1e-3,
        "wrist_2_joint.rz": 1e-3,
    }
    model = ErrorModel.from_mapping(ur, errors)
    parity = write_controller_file("joint-origins", ur, model, tmp_path / "k.yaml")
    assert parity.holds
    doc = yaml.safe_load((tmp_path / "k.yaml").read_text())
    kin = doc["kinematics"]
    assert list(kin) == [key for _, key in UR_JOINTS] + ["hash"] and kin["hash"].startswith("calib_")
    # the driver's chain: per joint origin(x y z, roll pitch yaw) then Rz(q), then the TCP
    qs = parity_poses(ur)
    t = np.broadcast_to(np.eye(4), (len(qs), 4, 4)).copy()
    from rxcomm.calibration.parity import axis_rotation

    for i, (_, key) in enumerate(UR_JOINTS):
        row = kin[key]
        t = t @ origin([row["x"], row["y"], row["z"]], [row["roll"], row["pitch"], row["yaw"]])
        t = t @ axis_rotation([0, 0, 1], qs[:, i])
    t = t @ origin(doc["tool"]["xyz_m"], doc["tool"]["rpy_rad"])
    assert compare("ur", ur, model.apply(ur), qs, t).max_position_m <= HOLD_M
    # the RX130L's joints are not a UR arm's: no such block
    write_controller_file("joint-origins", load_rx(), ErrorModel.zeros(load_rx()), tmp_path / "rx.yaml")
    assert "kinematics" not in yaml.safe_load((tmp_path / "rx.yaml").read_text())


def load_rx():
    from rxcomm.model.robot import load_robot

    return load_robot(ROBOT_DIR)


def test_the_report_lists_the_exports_with_their_parity(exports, tmp_path):
    import shutil

    out, _, _ = exports
    build = tmp_path / "build"
    build.mkdir()
    r = runner.invoke(app, ["report", str(build)])
    assert r.exit_code == 0, r.output
    assert "| controller exports in this build | not measured |" in (build / "report.md").read_text()
    shutil.copytree(out, build / "exports")
    (build / "report.md").unlink()
    r = runner.invoke(app, ["report", str(build)])
    assert r.exit_code == 0, r.output
    md = (build / "report.md").read_text()
    rows = yaml.safe_load((out / "parity.yaml").read_text())["exports"]
    assert "## Controller exports (exports/)" in md and f"| files written | {len(rows)} |" in md
    for name in ("calibration.urdf", "calibration.mdh-hayati.yaml", "calibration.joint-origins.yaml"):
        assert f"| exports/{name} |" in md
    mdh = next(r for r in rows if r["format"] == "mdh")["parity"]["max_position_m"]
    assert f"| plain MDH residual | {mdh * 1e3:.3g} mm |" in md
    assert "no: mdh cannot hold this calibration" in md


def test_a_joint_trajectory_written_elsewhere_is_read_and_a_point_beyond_a_limit_refused(tmp_path, rx130l):
    names = list(rx130l.joint_names)
    q0 = [float(v) for v in Q0]
    far = list(q0)
    far[2] = float(rx130l.q_max[2]) + 0.2  # joint_3 past its upper limit
    empty = {"velocities": [], "accelerations": [], "effort": []}  # as another tool writes it
    times = ((0, 0), (1, 500_000_000), (3, 0))
    doc = {
        "joint_names": names,
        "points": [
            {"positions": p, **empty, "time_from_start": {"sec": s, "nanosec": ns}}
            for p, (s, ns) in zip((q0, far, q0), times, strict=True)
        ],
    }
    path = tmp_path / "elsewhere.yaml"
    path.write_text(yaml.safe_dump(doc))
    traj, got = read_ros2_trajectory(path)
    assert got == names and np.array_equal(traj.t, [0.0, 1.5, 3.0]) and not traj.qd.any()
    r = runner.invoke(
        app,
        [
            "run",
            str(path),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:9",
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    )
    assert r.exit_code == 5, r.output  # refused before the gateway (a contact would exit 4)
    assert "points[1]" in r.output and "joint_3" in r.output and "position" in r.output
    doc["joint_names"] = names[::-1]
    path.write_text(yaml.safe_dump(doc))
    r = runner.invoke(
        app,
        [
            "run",
            str(path),
            "--robot",
            str(ROBOT_DIR),
            "--gateway",
            "127.0.0.1:9",
            "-o",
            str(tmp_path / "l.mcap"),
        ],
    )
    assert r.exit_code == 2 and "joint_names" in r.output, r.output
