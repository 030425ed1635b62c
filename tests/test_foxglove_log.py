"""Foxglove-native run logs: frame transforms from FK in the well-known schema, joint names, epoch
time stamps, and the shipped layout naming channels a run log has."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from rxcomm.execution.frames import DEMAND_PREFIX, link_transforms, link_tree, tcp_poses
from rxcomm.io.run_log import read_run_log
from rxcomm.model.kinematics import frame_placement
from rxcomm.stages import run as run_stage

from .runs import DQ, Q0, ROBOT_DIR, cosine_plan, gw, save_plan, start_cell

pytestmark = pytest.mark.socket  # the run log comes from a run on a served cell

LAYOUT = Path(__file__).parents[1] / "docs" / "foxglove" / "rxcomm-layout.json"


def _quat_matrix(xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = xyzw
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_link_transforms_chain_to_the_fk_of_the_tcp(rx130l):
    """Composing the logged parent->child transforms root to TCP gives the model's FK (1e-12 m)."""
    tree = link_tree(rx130l)
    assert tree.root == "base_link" and tree.pairs[0] == ("base_link", "link_1")
    assert tree.pairs[-1] == ("tool0", "tcp") and len(tree.pairs) == 8  # 6 joints, flange, TCP
    q = Q0 + 0.3 * DQ
    trans, rot = link_transforms(rx130l, tree, q[None])
    R, p = np.eye(3), np.zeros(3)
    for i in range(len(tree.pairs)):
        p = p + R @ trans[0, i]
        R = R @ _quat_matrix(rot[0, i])
    fk = frame_placement(rx130l, rx130l.create_data(), q, rx130l.tcp_frame_id)
    assert np.allclose(p, fk.translation, atol=1e-12) and np.allclose(R, fk.rotation, atol=1e-12)
    pos, ori = tcp_poses(rx130l, q[None])
    assert np.allclose(pos[0], fk.translation) and np.allclose(_quat_matrix(ori[0]), fk.rotation)
    assert tree.prefixed(DEMAND_PREFIX)[:2] == (
        ("base_link", "demand/base_link"),
        ("demand/base_link", "demand/link_1"),
    )


@pytest.fixture(scope="module")
def run_log(tmp_path_factory, rx130l) -> tuple[Path, int]:
    tmp = tmp_path_factory.mktemp("fox")
    plan = save_plan(tmp / "plan.mcap", cosine_plan(Q0, 0.25 * DQ, 0.4))
    out = tmp / "log.mcap"
    srv = start_cell(rx130l)
    try:
        t0 = time.time_ns()
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(srv), show_progress=False)
    finally:
        srv.stop()
    return out, t0


def test_run_log_has_frame_transforms_joint_names_and_epoch_stamps(run_log, rx130l):
    path, started_ns = run_log
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        by_topic = {c.topic: (c, summary.schemas[c.schema_id]) for c in summary.channels.values()}
        ch, schema = by_topic["/run/tf"]
        assert schema.name == "foxglove.FrameTransforms" and schema.encoding == "jsonschema"
        assert ch.message_encoding == "json"
        assert by_topic["/run/tcp"][1].name == "foxglove.PoseInFrame"
        tf = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/run/tf"])]
        joints_ch, joints_schema = by_topic["/run/joints"]
        assert joints_schema.encoding == "protobuf" and joints_ch.message_encoding == "protobuf"
        assert json.loads(joints_ch.metadata["rxcomm/constants"])["joint_names"] == list(rx130l.joint_names)
    with open(path, "rb") as f:  # the protobuf messages decode with their schema (Foxglove does the same)
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        _, _, joint, body = next(reader.iter_decoded_messages(topics=["/run/joints"]))
    assert len(body.q_actual) == rx130l.n and body.tcp_error_m >= 0
    # epoch time: within the run
    now = time.time_ns()
    assert started_ns - 10**9 <= joint.log_time <= now
    first = tf[0]["transforms"]
    assert [(x["parent_frame_id"], x["child_frame_id"]) for x in first] == list(link_tree(rx130l).pairs)
    stamps = [x["transforms"][0]["timestamp"] for x in tf]
    ns = np.array([s["sec"] * 10**9 + s["nsec"] for s in stamps])
    assert np.all(ns >= started_ns - 10**9) and np.all(np.diff(ns) > 0)
    assert 40 <= 1e9 / np.median(np.diff(ns)) <= 50.001  # decimated to the 3D view's rate
    # the readers still see seconds from the start, and the joint names
    log = read_run_log(path)
    assert log.joints.t[0] == 0.0 and log.joints.constants["joint_names"] == list(rx130l.joint_names)
    assert "joint_names" not in log.joints.fields


def _layout_topics(node) -> set[str]:
    """Every topic a layout names: the part of a message path before the first '.' or '['."""
    out: set[str] = set()
    if isinstance(node, dict):
        for k, v in node.items():
            if (
                k in ("value", "topic", "topicPath", "jointStatesTopic")
                and isinstance(v, str)
                and v.startswith("/")
            ):
                out.add(v.split(".")[0].split("[")[0].split("{")[0])
            out |= _layout_topics(v)
        for k in node:  # 3D panel topic settings are keyed by topic
            if isinstance(k, str) and k.startswith("/"):
                out.add(k)
    elif isinstance(node, list):
        for v in node:
            out |= _layout_topics(v)
    return out


def _panels(node) -> list[dict]:
    if node.get("type") == "panel":
        return [node]
    return [p for item in node.get("items", []) for p in _panels(item["content"])]


def test_shipped_layout_parses_and_names_channels_a_run_log_has(run_log):
    layout = json.loads(LAYOUT.read_text())
    topics = _layout_topics(layout)
    panels = json.dumps(layout)
    assert (
        layout["version"] == 1
    )  # the layout model of the official foxglove-sdk (docs/foxglove/make_layout.py)
    kinds = [p["panelType"] for p in _panels(layout["content"])]
    assert kinds.count("Plot") >= 3 and "ThreeDee" in kinds, kinds
    with open(run_log[0], "rb") as f:
        channels = {c.topic for c in make_reader(f).get_summary().channels.values()}
    # the 3D panel takes every FrameTransforms channel (/run/tf, /run/tf_demand) by itself
    assert {"/run/joints", "/run/tcp", "/robot_description"} <= topics and "/run/tf" in channels
    assert topics <= channels, topics - channels
    for field in ("following_error", "tau_actual", "tcp_speed_m_s"):
        assert f"/run/joints.{field}" in panels, field


def test_tracker_poses_are_pose_in_frame_in_the_tracker_frame(tmp_path, rx130l):
    from rxcomm.execution.frames import FoxgloveFrames
    from rxcomm.io.mcap_io import McapWriter
    from rxcomm.schemas.trajectory import TrajectorySummary

    path = tmp_path / "x.mcap"
    t = np.arange(5) * 0.004
    pos = np.column_stack([1.0 + t, np.zeros(5), 0.5 * np.ones(5)])
    wxyz = np.tile([np.cos(0.2), 0.0, 0.0, np.sin(0.2)], (5, 1))  # 0.4 rad about z
    with McapWriter(path, TrajectorySummary.envelope({}, {}, {})) as w:
        frames = FoxgloveFrames(w, rx130l, 0.0004)
        frames.tracker(t, pos, wxyz, 50.0)  # at most 50 Hz: every sample
        origin = w.time_origin_ns
    assert frames.topics()[-1].topic == "/run/tracker_pose" and frames.topics()[-1].n_messages == 5
    with open(path, "rb") as f:
        reader = make_reader(f)
        msgs = [
            (s.name, m.log_time, json.loads(m.data))
            for s, _, m in reader.iter_messages(["/run/tracker_pose"])
        ]
    assert [m[0] for m in msgs] == ["foxglove.PoseInFrame"] * 5
    name, log_ns, last = msgs[-1]
    assert log_ns == origin + 16_000_000 and last["frame_id"] == "tracker"
    assert last["timestamp"] == {"sec": log_ns // 10**9, "nsec": log_ns % 10**9}
    assert last["pose"]["position"] == {"x": 1.016, "y": 0.0, "z": 0.5}
    o = last["pose"]["orientation"]
    assert (
        (o["x"], o["y"]) == (0.0, 0.0) and np.isclose(o["z"], np.sin(0.2)) and np.isclose(o["w"], np.cos(0.2))
    )


def test_frame_transforms_template_is_the_json_of_the_message():
    from rxcomm.io.foxglove import frame_transforms, frame_transforms_json, frame_transforms_template

    pairs = [("base_link", "link_1"), ("link_1", 'odd"%name')]
    rng = np.random.default_rng(2)
    trans, rot = rng.standard_normal((2, 3)), rng.standard_normal((2, 4))
    ns = 1_796_000_000_123_456_789
    text = frame_transforms_json(frame_transforms_template(pairs), ns, trans, rot)
    assert json.loads(text) == frame_transforms(ns, pairs, trans, rot)


def test_run_with_a_calibration_has_the_tracker_frame(tmp_path, rx130l):
    """`run --calibration`: the log's tree has `tracker` under the root link at the inverse of the
    calibration's tracker_to_base (1e-12), the summary lists /run/tf_tracker, /robot_description is
    the calibrated URDF and /run/tcp the calibrated FK (a 0.1 mm base error moves it 0.1 mm); a
    calibration of other joints is exit 2 before anything moves."""
    import pinocchio as pin
    import yaml

    from rxcomm.calibration.loading import load_calibrated_robot, load_calibration, parameter_names_from
    from rxcomm.calibration.urdf import calibrated_urdf_text
    from rxcomm.errors import InputError
    from rxcomm.io.yaml_io import write_yaml_artefact
    from rxcomm.model.geometric_errors import placement_to_se3
    from rxcomm.schemas.cell import Placement

    from .artefacts import synthetic_calibration

    xyz, rpy = (2.5, -0.7, 0.2), (0.01, -0.03, 2.4)
    names = list(parameter_names_from(rx130l.joint_names))  # all 48, as calibrate writes them
    cal = synthetic_calibration(rx130l, {"base.tx": 1e-4}, names=names).model_copy(
        update={"tracker_to_base": Placement(xyz_m=xyz, rpy_rad=rpy)}
    )
    cal_file = write_yaml_artefact(tmp_path / "calibration.yaml", cal)
    plan = save_plan(tmp_path / "plan.mcap", cosine_plan(Q0, 0.25 * DQ, 0.4))
    out = tmp_path / "log.mcap"
    srv = start_cell(rx130l)
    try:
        run_stage.execute(plan, ROBOT_DIR, out, gateway=gw(srv), show_progress=False, calibration=cal_file)
    finally:
        srv.stop()
    with open(out, "rb") as f:
        msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(["/run/tf_tracker"])]
    assert len(msgs) == 1
    (tf,) = msgs[0]["transforms"]
    assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("base_link", "tracker")
    tr, r = tf["translation"], tf["rotation"]
    got = pin.XYZQUATToSE3(np.array([tr["x"], tr["y"], tr["z"], r["x"], r["y"], r["z"], r["w"]]))
    expected = placement_to_se3(xyz, rpy).inverse()
    np.testing.assert_allclose(got.homogeneous, expected.homogeneous, rtol=0, atol=1e-12)
    with open(out, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        (urdf,) = [json.loads(m.data)["data"] for _, _, m in reader.iter_messages(["/robot_description"])]
        tcp0 = json.loads(next(m for _, _, m in reader.iter_messages(["/run/tcp"])).data)["pose"]["position"]
    assert (
        urdf
        == calibrated_urdf_text(rx130l, load_calibration(cal_file)[0])
        != ROBOT_DIR.joinpath("rx130l.urdf").read_text()
    )
    q0 = read_run_log(out).joints.fields["q_actual"][0]
    calibrated = load_calibrated_robot(rx130l, cal_file)
    fk = frame_placement(calibrated, calibrated.create_data(), q0, calibrated.tcp_frame_id).translation
    nominal = frame_placement(rx130l, rx130l.create_data(), q0, rx130l.tcp_frame_id).translation
    got_tcp = np.array([tcp0[a] for a in "xyz"])
    np.testing.assert_allclose(got_tcp, fk, rtol=0, atol=1e-6)  # q_actual is stored as float32
    assert np.linalg.norm(got_tcp - nominal) > 5e-5
    meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
    assert "/run/tf_tracker" in [t["topic"] for t in meta["topics"]] and "calibration" in meta["inputs"]
    bad = cal.model_copy(update={"joint_names": [f"j{i}" for i in range(6)]})
    bad_file = write_yaml_artefact(tmp_path / "bad.yaml", bad)
    with pytest.raises(InputError, match="joint"):
        run_stage.execute(plan, ROBOT_DIR, tmp_path / "b.mcap", show_progress=False, calibration=bad_file)
