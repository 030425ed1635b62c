"""A run log with tracker data carries ``/run/tracker_pose`` for Foxglove's 3D panel: the
``/run/tracker`` samples themselves (at most the 3D view's rate), PoseInFrame in frame ``tracker``."""

from __future__ import annotations

import json

import numpy as np
from mcap.reader import make_reader

from rxcomm.execution.log import RunLogWriter
from rxcomm.execution.plan import prepare_plan
from rxcomm.io.mcap_io import recover_mcap
from rxcomm.model.dynamics import prior_parameters
from rxcomm.schemas.run_log import FOXGLOVE_RATE_HZ, TrackerChannel

from .runs import CYCLE, DQ, Q0, cosine_plan


def _tracker_log(tmp_path, rx130l, rate_hz: float):
    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 1.0), prior_parameters(rx130l), CYCLE)
    writer = RunLogWriter(
        tmp_path / "log.mcap", rx130l, inputs={}, settings={}, feedforward="prior", embedded_cell=False
    )
    writer.begin(plan, 1, CYCLE)
    writer.records(0, plan.q, plan.tau_ff)
    rng = np.random.default_rng(3)
    t_tracker = 100.0 + np.arange(int(0.2 * rate_hz)) / rate_hz  # the tracker's own clock
    pos = np.array([1.2, -0.3, 0.8]) + 1e-3 * rng.standard_normal((len(t_tracker), 3))
    quat = rng.standard_normal((len(t_tracker), 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    offset = 100.0 + 2.5 / rate_hz  # the first three samples fall before the stream start: dropped
    channel = TrackerChannel(source="csv", rate_hz=rate_hz, n_samples=0, alignment="trigger", offset_s=offset)
    writer.tracker(t_tracker, pos, quat, channel)
    topics = {t.topic: t for t in writer._foxglove.topics()}
    part = writer.abandon()
    return part, topics


def _poses(path):
    with open(path, "rb") as f:
        return [
            (m.log_time, json.loads(m.data))
            for _, _, m in make_reader(f).iter_messages(["/run/tracker_pose"])
        ]


def test_tracker_pose_is_the_tracker_rows_at_the_view_rate(tmp_path, rx130l):
    part, topics = _tracker_log(tmp_path, rx130l, 1000.0)
    rows = recover_mcap(part).topics["/run/tracker"]
    poses = _poses(part)
    stride = int(np.ceil(1000.0 / FOXGLOVE_RATE_HZ))  # 20: 50 Hz of a 1 kHz tracker
    assert len(rows) == 197 and len(poses) == len(range(0, 197, stride)) == 10
    assert topics["/run/tracker_pose"].n_messages == 10
    assert topics["/run/tracker_pose"].period_s == stride / 1000.0
    for k, (log_ns, p) in enumerate(poses):
        i = k * stride
        assert p["frame_id"] == "tracker"
        assert abs((log_ns - poses[0][0]) * 1e-9 - (rows.t[i] - rows.t[0])) < 1e-9  # same log times
        pos = [p["pose"]["position"][a] for a in "xyz"]
        o = p["pose"]["orientation"]
        np.testing.assert_allclose(pos, rows.fields["position_m"][i], rtol=0, atol=1e-12)
        np.testing.assert_allclose(
            [o["w"], o["x"], o["y"], o["z"]], rows.fields["quaternion_wxyz"][i], rtol=0, atol=1e-12
        )


def test_a_slow_tracker_gets_every_sample(tmp_path, rx130l):
    part, topics = _tracker_log(tmp_path, rx130l, 40.0)
    rows = recover_mcap(part).topics["/run/tracker"]
    poses = _poses(part)
    assert len(poses) == len(rows) == 5 and topics["/run/tracker_pose"].period_s == 1 / 40.0
    np.testing.assert_allclose(
        [[p["pose"]["position"][a] for a in "xyz"] for _, p in poses], rows.fields["position_m"], atol=1e-12
    )


def test_a_calibration_puts_the_tracker_frame_in_the_tree(tmp_path, rx130l):
    """run --calibration: /run/tf_tracker holds root link -> tracker once, the inverse of the
    calibration's tracker_to_base (to 1e-12); without one there is no such channel."""
    import pinocchio as pin

    from rxcomm.execution.frames import CalibratedView
    from rxcomm.model.geometric_errors import placement_to_se3

    plan = prepare_plan(rx130l, cosine_plan(Q0, DQ, 1.0), prior_parameters(rx130l), CYCLE)
    t2b = placement_to_se3([2.1, -0.4, 0.3], [0.02, -0.05, 1.3])
    for name, given in (("with.mcap", t2b), ("without.mcap", None)):
        writer = RunLogWriter(
            tmp_path / name, rx130l, inputs={}, settings={}, feedforward="prior", embedded_cell=False,
            view=None if given is None else CalibratedView(rx130l, "<robot/>", given),
        )  # fmt: skip
        writer.begin(plan, 1, CYCLE)
        writer.records(0, plan.q[:10], plan.tau_ff[:10])
        topics = [t.topic for t in writer._foxglove.topics()]
        part = writer.abandon()
        with open(part, "rb") as f:
            msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(["/run/tf_tracker"])]
        if given is None:
            assert msgs == [] and "/run/tf_tracker" not in topics
            continue
        assert len(msgs) == 1 and "/run/tf_tracker" in topics
        (tf,) = msgs[0]["transforms"]
        assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("base_link", "tracker")
        tr, r = tf["translation"], tf["rotation"]
        got = pin.XYZQUATToSE3(np.array([tr["x"], tr["y"], tr["z"], r["x"], r["y"], r["z"], r["w"]]))
        expected = t2b.inverse()
        np.testing.assert_allclose(got.homogeneous, expected.homogeneous, rtol=0, atol=1e-12)
        assert not np.allclose(got.homogeneous, t2b.homogeneous, atol=1e-3)  # not tracker_to_base itself
