"""The tracker during motion: the simulated cell's samples (rate, stamps, latency), a real tracker's
CSV export, and their alignment to the joint log (trigger, cross-correlation) with known shifts."""

from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest
import yaml
from mcap.reader import make_reader

from rxcomm.acceptance.alignment import align, tracker_channel, trigger_offset
from rxcomm.cell.tracker import PRETRIGGER_S, MotionTracker, SimulatedTracker
from rxcomm.errors import InputError
from rxcomm.io.run_log import read_run_log
from rxcomm.io.tracker_csv import TrackerExport, read_tracker_csv, write_tracker_csv
from rxcomm.io.yaml_io import read_yaml_model
from rxcomm.model.kinematics import frame_placement, quaternion_wxyz
from rxcomm.schemas.truth import CellTruth

from .conftest import SAMPLES

CYCLE = 0.0004
TRUTH = SAMPLES / "rx130l" / "truth.yaml"


@pytest.fixture(scope="module")
def truth() -> CellTruth:
    return read_yaml_model(TRUTH, CellTruth)


def joint_move(duration_s: float, dt: float, dq=(1.2, 0.5, -0.5, 0.3, -0.2, 0.4), rest_s: float = 0.2):
    """A rest-to-rest cycloidal joint move with rests before and after, sampled every dt."""
    t = np.arange(int(round((duration_s + 2 * rest_s) / dt)) + 1) * dt
    tau = np.clip((t - rest_s) / duration_s, 0, 1)
    s = tau - np.sin(2 * np.pi * tau) / (2 * np.pi)
    return t, np.outer(s, dq) + np.array([0.0, -0.3, 0.4, 0.0, 0.6, 0.0])


def test_motion_tracker_samples_at_its_rate_stamped_late_by_the_latency(rx130l, truth):
    tracker = SimulatedTracker(rx130l, truth, np.random.default_rng(1))
    mt = MotionTracker(tracker, 1000.0, 0.0071, rx130l.n)
    t, q = joint_move(0.5, CYCLE)
    trigger_at = 0.3
    for ti, qi in zip(t, q, strict=True):
        if abs(ti - trigger_at) < CYCLE / 2:
            mt.trigger(ti)
        mt.step(ti, qi)
    ex = mt.export()
    assert ex.trigger_s == pytest.approx(trigger_at)
    np.testing.assert_allclose(np.diff(ex.t_s), 1e-3, atol=1e-12)  # 1 kHz on the tracker clock
    taken = ex.t_s - 0.0071  # when each was measured (cell time)
    assert taken[0] == pytest.approx(trigger_at - PRETRIGGER_S, abs=1e-3)  # the pre-trigger samples
    assert taken[-1] == pytest.approx(t[-1], abs=1e-3)
    assert ex.rate_hz == pytest.approx(1000.0)
    # each sample is the true pose at the instant it was taken, within the tracker's noise
    sigma = truth.noise.tracker_position_sigma_m
    for k in range(0, ex.n, 97):
        q_k = np.array([np.interp(taken[k], t, q[:, j]) for j in range(rx130l.n)])
        err = ex.position_m[k] - tracker.true_pose(q_k).translation
        assert np.all(np.abs(err) < 5 * sigma), (k, err)


def test_motion_tracker_keeps_only_the_pretrigger_window_before_a_trigger(rx130l, truth):
    mt = MotionTracker(SimulatedTracker(rx130l, truth, np.random.default_rng(1)), 1000.0, 0.0, rx130l.n)
    q = np.zeros(rx130l.n)
    for k in range(int(20.0 / CYCLE)):  # 20 s standing, no stream: bounded memory
        mt.step(k * CYCLE, q)
    assert mt._n <= 4096 + 10
    mt.trigger(20.0)
    ex = mt.export()
    assert ex.t_s[0] >= 20.0 - PRETRIGGER_S - 1e-9 and ex.n <= 251


def tracker_view(robot, t_joint, q, shift_s: float, rate_hz: float, noise_m: float, seed: int = 0):
    """What a tracker in another frame reports of FK(q): stamps = instant + shift_s, 1/rate apart."""
    rng = np.random.default_rng(seed)
    frame = pin.SE3(pin.exp3(np.array([0.1, -0.2, 2.5])), np.array([3.0, -1.0, 0.4]))
    t_meas = np.arange(t_joint[0], t_joint[-1], 1.0 / rate_hz)
    qs = np.column_stack([np.interp(t_meas, t_joint, q[:, j]) for j in range(robot.n)])
    data = robot.create_data()
    poses = [frame * frame_placement(robot, data, qi, robot.tcp_frame_id) for qi in qs]
    pos = np.array([m.translation for m in poses]) + rng.normal(0, noise_m, (len(qs), 3))
    quat = np.array([quaternion_wxyz(m.rotation) for m in poses])
    return TrackerExport(t_meas + shift_s, pos, quat, None, source="csv")


@pytest.mark.parametrize("shift_s", [-0.0123, 0.0071, 1234.5678])
def test_cross_correlation_recovers_a_known_shift_of_a_csv_export(tmp_path, rx130l, shift_s):
    """A tracker CSV without trigger, its clock shifted by `shift_s` and in its own frame: the
    cross-correlation of the TCP velocities puts it on the joint log within a tenth of a cycle."""
    dt = CYCLE
    t, q = joint_move(1.0, dt)
    ex = tracker_view(rx130l, t, q, shift_s, 1000.0, 5e-5)
    f = write_tracker_csv(tmp_path / "tracker.csv", ex)
    back = read_tracker_csv(f)
    assert back.n == ex.n and back.trigger_s is None
    np.testing.assert_allclose(back.position_m, ex.position_m, atol=1e-8)
    ch = tracker_channel(rx130l, back, q, dt, method="auto", source_file=f.name)
    assert ch.alignment == "cross-correlation" and ch.source == "csv"
    assert ch.offset_s == pytest.approx(shift_s, abs=0.1 * dt)
    assert ch.correlation > 0.99


def test_trigger_alignment_is_the_trigger_stamp_plus_one_setpoint(rx130l):
    t, q = joint_move(1.0, CYCLE)
    ex = tracker_view(rx130l, t, q, 0.0, 1000.0, 0.0)
    data = rx130l.create_data()
    p_fk = np.array([frame_placement(rx130l, data, qi, rx130l.tcp_frame_id).translation for qi in q])
    a = align(ex.t_s, ex.position_m, t, p_fk, trigger_s=5.0, sample_s=CYCLE, method="trigger")
    assert a.offset_s == trigger_offset(5.0, CYCLE) == pytest.approx(5.0 + CYCLE)
    with pytest.raises(InputError, match="no trigger_s"):
        align(ex.t_s, ex.position_m, t, p_fk, trigger_s=None, sample_s=CYCLE, method="trigger")


def test_a_lost_beam_keeps_the_trigger_alone(rx130l):
    t, q = joint_move(1.0, CYCLE)
    ex = tracker_view(rx130l, t, q, 0.0035, 1000.0, 5e-5)
    keep = (ex.t_s < 0.4) | (ex.t_s > 0.9)  # half a second without samples
    p_fk = np.array(
        [frame_placement(rx130l, rx130l.create_data(), qi, rx130l.tcp_frame_id).translation for qi in q]
    )
    a = align(ex.t_s[keep], ex.position_m[keep], t, p_fk, trigger_s=-CYCLE, sample_s=CYCLE)
    assert a.method == "trigger" and a.offset_s == pytest.approx(0.0)
    with pytest.raises(InputError, match="covers"):
        align(ex.t_s[keep], ex.position_m[keep], t, p_fk, trigger_s=None, sample_s=CYCLE)


@pytest.mark.parametrize(
    "text, field",
    [
        ("x_m,y_m,z_m\n1,2,3\n", "t_s"),
        ("t_s,x_m,y_m\n0,1,2\n", "x_m"),
        ("t_s,x_m,y_m,z_m\n0,1,2,3\n0,1,2,3\n", "t_s"),
        ("t_s,x_m,y_m,z_m\n0,1,2,3\n0.001,1,zz,3\n", "y_m"),
        ("t_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,1,2,3,1,0,0,0\n0.001,1,2,3,2,0,0,0\n", "qw"),
        ("# trigger_s: soon\nt_s,x_m,y_m,z_m\n0,1,2,3\n0.001,1,2,3\n", "trigger_s"),
    ],
)
def test_bad_tracker_csv_names_the_field(tmp_path, text, field):
    f = tmp_path / "t.csv"
    f.write_text(text)
    with pytest.raises(InputError) as e:
        read_tracker_csv(f)
    assert e.value.field == field and str(f) in str(e.value)


def test_csv_in_millimetres_and_the_trigger_line(tmp_path):
    f = tmp_path / "t.csv"
    f.write_text(
        "# exported by a tracker\n# trigger_s: 12.5\nt_s,x_mm,y_mm,z_mm\n12.0,1000,2,3\n12.001,1001,2,3\n"
    )
    ex = read_tracker_csv(f)
    assert ex.trigger_s == 12.5
    np.testing.assert_allclose(ex.position_m[1], [1.001, 0.002, 0.003])
    assert np.all(np.isnan(ex.quaternion_wxyz))  # position only


@pytest.mark.slow
@pytest.mark.parametrize("latency_s", [0.0, 0.0071])
def test_run_records_the_tracker_aligned_within_one_drive_cycle(tmp_path, rx130l, latency_s):
    """The embedded cell's tracker with an injected latency: /run/tracker reads back at 1 kHz and the
    run's alignment (trigger refined by cross-correlation) finds the latency within one drive cycle."""
    from rxcomm.io.trajectory import Trajectory
    from rxcomm.stages import run as run_stage

    from .runs import save_plan

    raw = yaml.safe_load(TRUTH.read_text())
    raw["robot"] = str(TRUTH.parent.resolve())
    raw["noise"]["tracker_latency_s"] = latency_s
    truth_file = tmp_path / "truth.yaml"
    truth_file.write_text(yaml.safe_dump(raw))
    dt = rx130l.drives.cycle_s
    t = np.arange(int(round(1.0 / dt)) + 1) * dt
    tau = t / t[-1]
    s = tau - np.sin(2 * np.pi * tau) / (2 * np.pi)
    sd = (1 - np.cos(2 * np.pi * tau)) / t[-1]
    sdd = 2 * np.pi * np.sin(2 * np.pi * tau) / t[-1] ** 2
    dq = np.array([0.8, 0.4, -0.4, 0.0, 0.0, 0.0])
    plan = save_plan(
        tmp_path / "plan.mcap", Trajectory(t, np.outer(s, dq), np.outer(sd, dq), np.outer(sdd, dq))
    )
    out = tmp_path / "log.mcap"
    run_stage.execute(
        plan, SAMPLES / "rx130l", out, truth=truth_file, interpolation_ratio=1, show_progress=False
    )
    meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
    ch = meta["tracker"]
    assert ch["source"] == "simulated-cell" and ch["alignment"] == "trigger+cross-correlation"
    assert ch["rate_hz"] == pytest.approx(1000.0, rel=1e-9)
    found = ch["offset_s"] - ch["trigger_offset_s"]
    assert found == pytest.approx(latency_s, abs=dt), found  # within one drive cycle
    log = read_run_log(out)
    tr = log.tracker
    assert len(tr) == ch["n_samples"] >= 1000
    np.testing.assert_allclose(np.diff(tr.t), 1e-3, atol=1e-9)  # reads back at the configured rate
    np.testing.assert_allclose(tr.t, tr.t_tracker_s - ch["offset_s"], atol=1e-9)
    assert any(t["topic"] == "/run/tracker" for t in meta["topics"])
    # the 3D view's copy: every 20th of the 1 kHz samples (50 Hz), the same poses
    with open(out, "rb") as f:
        poses = [
            json.loads(m.data)["pose"] for _, _, m in make_reader(f).iter_messages(["/run/tracker_pose"])
        ]
    assert len(poses) == len(range(0, len(tr), 20))
    got = np.array([[p["position"][a] for a in "xyz"] for p in poses])
    np.testing.assert_allclose(got, tr.fields["position_m"][::20], rtol=0, atol=1e-12)


@pytest.mark.slow
def test_import_tracker_puts_a_csv_on_a_run_log(tmp_path, rx130l):
    """A run on ideal drives (no tracker), a tracker CSV of that motion in its own frame and clock
    (shifted 1234.5678 s, no trigger): `import-tracker` writes the log with /run/tracker aligned."""
    from typer.testing import CliRunner

    from rxcomm.cell.backend import IdealBackend
    from rxcomm.cell.server import CellServer, ServerConfig
    from rxcomm.cli import app
    from rxcomm.io.trajectory import Trajectory
    from rxcomm.stages import run as run_stage

    from .runs import save_plan

    t, q = joint_move(1.0, CYCLE, dq=(0.5, 0.3, -0.3, 0.2, -0.2, 0.3))
    qd = np.gradient(q, t, axis=0)
    plan = save_plan(tmp_path / "plan.mcap", Trajectory(t, q, qd, np.gradient(qd, t, axis=0)))
    backend = IdealBackend(q[0], rated_torque_nm=np.asarray(rx130l.tau_max))
    with CellServer(backend, ServerConfig()) as srv:
        log = tmp_path / "log.mcap"
        gw = f"127.0.0.1:{srv.port}"
        run_stage.execute(
            plan, SAMPLES / "rx130l", log, gateway=gw, interpolation_ratio=1, show_progress=False
        )
    j = read_run_log(log).joints
    csv = write_tracker_csv(
        tmp_path / "tracker.csv", tracker_view(rx130l, j.t, j.q_actual, 1234.5678, 1000, 5e-5)
    )
    out = tmp_path / "tracked.mcap"
    res = CliRunner().invoke(
        app,
        [
            "import-tracker",
            str(log),
            "--tracker-csv",
            str(csv),
            "--robot",
            str(SAMPLES / "rx130l"),
            "-o",
            str(out),
        ],
    )
    assert res.exit_code == 0, res.output
    meta = yaml.safe_load(out.with_suffix(".yaml").read_text())
    ch = meta["tracker"]
    assert (
        ch["source"] == "csv"
        and ch["source_file"] == "tracker.csv"
        and ch["alignment"] == "cross-correlation"
    )
    assert ch["offset_s"] == pytest.approx(1234.5678, abs=0.1 * CYCLE)
    assert "tracker csv" in meta["inputs"]
    back = read_run_log(out)
    assert len(back.joints) == len(j) and np.allclose(back.joints.q_actual, j.q_actual, atol=1e-9)
    for k, v in j.fields.items():  # the copy's joints on the same grids: the source's values exactly
        np.testing.assert_array_equal(back.joints[k], v, err_msg=k)
    assert len(back.tracker) == ch["n_samples"] > 900
    # importing twice is refused, naming the field
    res2 = CliRunner().invoke(
        app,
        [
            "import-tracker",
            str(out),
            "--tracker-csv",
            str(csv),
            "--robot",
            str(SAMPLES / "rx130l"),
            "-o",
            str(tmp_path / "x.mcap"),
        ],
    )
    assert res2.exit_code == 2 and "tracker channel already" in res2.output


def test_batched_measurement_is_the_per_sample_true_pose(rx130l, truth):
    """measure_many (the motion tracker's export) = true_pose sample by sample: the same kinematics,
    errors, frame and compliance; the deflection interpolated between every 25th state costs < 0.1 µm."""
    quiet = truth.noise.model_copy(
        update={"tracker_position_sigma_m": 0.0, "tracker_orientation_sigma_rad": 0.0}
    )
    tracker = SimulatedTracker(rx130l, truth.model_copy(update={"noise": quiet}), np.random.default_rng(0))
    qs = np.random.default_rng(1).uniform(-0.5, 0.5, (50, 6))
    p, r, visible = tracker.measure_many(qs, deflection_every=1)
    assert visible.all()
    for i, q in enumerate(qs):
        m = tracker.true_pose(q)
        np.testing.assert_allclose(p[i], m.translation, atol=1e-12)
        np.testing.assert_allclose(r[i], m.rotation, atol=1e-12)
    line = np.linspace(qs[0], qs[1], 1000)
    p_line, _, _ = tracker.measure_many(line)
    ref = np.array([tracker.true_pose(q).translation for q in line])
    assert np.abs(p_line - ref).max() < 1e-7


def test_a_samples_noise_does_not_depend_on_the_batch_it_is_measured_in(rx130l, truth):
    """The export measures every sample since the pre-trigger at once, and how many there are depends on
    when the master asks: sample i's noise (position AND orientation) must be the same in a short and a
    long batch, or a re-run of the same chain reports other orientation figures (it did: RP_a 0.0008°
    vs 0.00042° on two builds of one commit)."""
    qs = np.random.default_rng(1).uniform(-0.5, 0.5, (40, 6))
    short = SimulatedTracker(rx130l, truth, np.random.default_rng(7)).measure_many(
        qs[:10], deflection_every=1
    )
    long = SimulatedTracker(rx130l, truth, np.random.default_rng(7)).measure_many(qs, deflection_every=1)
    np.testing.assert_array_equal(short[0], long[0][:10])
    np.testing.assert_array_equal(short[1], long[1][:10])
    assert not np.allclose(
        long[1][0], SimulatedTracker(rx130l, truth, np.random.default_rng(8)).measure_many(qs)[1][0]
    )
