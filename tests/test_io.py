"""Artefact I/O: YAML envelopes, atomic writes, MCAP round trip, kill-and-recover, trajectories."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from pydantic import BaseModel, ConfigDict, ValidationError

from rxcomm.errors import InputError
from rxcomm.io.files import atomic_write_bytes, atomic_write_text
from rxcomm.io.mcap_io import (
    ENVELOPE_RECORD,
    RECOVERED_RECORD,
    McapWriter,
    number_field,
    read_mcap,
    recover_mcap,
    vector_field,
)
from rxcomm.io.trajectory import InvalidTrajectory, Trajectory, load_trajectory_mcap, save_trajectory_mcap
from rxcomm.io.yaml_io import read_yaml_artefact, read_yaml_model, write_summary_yaml, write_yaml_artefact
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.plain import sha256_file
from rxcomm.schemas.trajectory import TrajectorySummary


class Joint(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    offset_rad: float


class DemoSettings(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_poses: int = 32
    tol_m: float = 1e-5


class DemoSummary(BaseModel):
    model_config = ConfigDict(extra="forbid")
    n_selected: int
    err_m: float | None = None
    ok: bool | None = None
    per_joint_rad: list[float] | None = None


class Demo(Artefact[DemoSettings, DemoSummary], kind="rxcomm/Demo", schema_version=1):
    joints: list[Joint]
    params_m: list[float]


def _demo(tmp_path: Path) -> Demo:
    robot = tmp_path / "robot.urdf"
    robot.write_text("<robot name='r'/>")
    summary = {
        "n_selected": np.int64(32),
        "err_m": np.float64(1.25e-4),
        "ok": True,
        "per_joint_rad": np.arange(6.0),
    }
    env = Demo.envelope({"robot": robot}, DemoSettings(), summary)
    joints = [Joint(name=f"j{i}", offset_rad=0.01 * i) for i in range(2)]
    return Demo(**env, joints=joints, params_m=np.array([0.1, -2.5e-3]))


def _write_yaml(path: Path, data: dict) -> Path:
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ---------------------------------------------------------------- YAML artefacts


def test_yaml_round_trip_keeps_types_order_and_hashes(tmp_path: Path) -> None:
    art = _demo(tmp_path)
    out = write_yaml_artefact(tmp_path / "demo.yaml", art)
    back = read_yaml_artefact(out, Demo)
    assert back == art
    assert back.inputs["robot"] == hashlib.sha256(b"<robot name='r'/>").hexdigest()
    assert back.settings.model_dump() == {"n_poses": 32, "tol_m": 1e-5}
    assert type(back.summary.n_selected) is int and back.summary.ok is True
    assert back.summary.err_m == 1.25e-4 and back.summary.per_joint_rad == [
        0.0,
        1.0,
        2.0,
        3.0,
        4.0,
        5.0,
    ]
    assert back.created.utcoffset().total_seconds() == 0
    text = out.read_text()
    assert list(yaml.safe_load(text))[:8] == [
        "kind",
        "schema_version",
        "created",
        "rxcomm_version",
        "code_identity",
        "inputs",
        "settings",
        "summary",
    ]
    assert "per_joint_rad: [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]" in text  # short number lists stay on one line
    assert not (tmp_path / "demo.yaml.part").exists()


@pytest.mark.parametrize(
    ("edit", "field", "words"),
    [
        (lambda d: d.update(kind="rxcomm/Calibration"), "kind", "unknown kind 'rxcomm/Calibration'"),
        (lambda d: d.pop("kind"), "kind", "missing"),
        (lambda d: d.update(schema_version=2), "schema_version", "unsupported schema_version 2"),
        (lambda d: d.update(bogus=1), "bogus", "unknown key"),
        (lambda d: d["joints"][1].update(offest_rad=0.0), "joints.1.offest_rad", "unknown key"),
        (lambda d: d["joints"][0].update(offset_rad="abc"), "joints.0.offset_rad", "valid number"),
        (lambda d: d["inputs"].update(robot="xyz"), "inputs.robot", "pattern"),
        (lambda d: d["summary"].pop("n_selected"), "summary.n_selected", "missing"),
        (lambda d: d.update(created="2025-01-01T00:00:00"), "created", "time zone"),
    ],
)
def test_yaml_refusals_name_file_and_field(tmp_path: Path, edit, field: str, words: str) -> None:
    data = _demo(tmp_path).model_dump(mode="json")
    edit(data)
    path = _write_yaml(tmp_path / "bad.yaml", data)
    with pytest.raises(InputError) as ei:
        read_yaml_artefact(path, Demo)
    assert ei.value.file == str(path) and ei.value.field == field
    assert words in ei.value.reason
    assert str(path) in str(ei.value) and field in str(ei.value)


def test_yaml_file_level_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="file not found") as ei:
        read_yaml_artefact(tmp_path / "none.yaml", Demo)
    assert ei.value.file == str(tmp_path / "none.yaml")
    bad = tmp_path / "syntax.yaml"
    bad.write_text("kind: rxcomm/Demo\nsummary: [1, 2\nother: 3\n")
    with pytest.raises(InputError, match=r"YAML syntax error at line \d+"):
        read_yaml_artefact(bad, Demo)
    dup = tmp_path / "dup.yaml"
    dup.write_text("kind: a\nkind: b\n")
    with pytest.raises(InputError, match="line 2.*duplicate key 'kind'"):
        read_yaml_artefact(dup, Demo)
    lst = tmp_path / "list.yaml"
    lst.write_text("- 1\n- 2\n")
    with pytest.raises(InputError, match="expected a mapping"):
        read_yaml_artefact(lst, Demo)


def test_read_yaml_model_for_config_files(tmp_path: Path) -> None:
    good = _write_yaml(tmp_path / "cfg.yaml", {"n_poses": 8})
    assert read_yaml_model(good, DemoSettings) == DemoSettings(n_poses=8)
    bad = _write_yaml(tmp_path / "cfg2.yaml", {"n_poses": 8, "tol": 1})
    with pytest.raises(InputError) as ei:
        read_yaml_model(bad, DemoSettings)
    assert (ei.value.file, ei.value.field, ei.value.reason) == (str(bad), "tol", "unknown key")


def test_artefact_constructor_refuses_wrong_kind(tmp_path: Path) -> None:
    data = _demo(tmp_path).model_dump()
    with pytest.raises(ValidationError, match="expected 'rxcomm/Demo'"):
        Demo(**{**data, "kind": "rxcomm/Other"})


# ---------------------------------------------------------------- atomic writes


def test_atomic_write_replaces_or_leaves_old_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    p = tmp_path / "out.txt"
    atomic_write_text(p, "old\n")
    assert p.read_text() == "old\n" and sha256_file(p) == hashlib.sha256(b"old\n").hexdigest()
    with pytest.raises(TypeError):
        atomic_write_bytes(p, "not bytes")  # type: ignore[arg-type]  # fails while writing
    assert p.read_text() == "old\n" and sorted(os.listdir(tmp_path)) == ["out.txt"]

    def boom(*_a: object) -> None:
        raise OSError("rename failed")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError, match="rename failed"):
        atomic_write_text(p, "new\n")
    assert p.read_text() == "old\n" and sorted(os.listdir(tmp_path)) == ["out.txt"]


# ---------------------------------------------------------------- MCAP


def _env(tmp_path: Path) -> dict:
    return _demo(tmp_path).envelope_dict()


def test_mcap_round_trip_types_timestamps_and_foxglove_conventions(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    n = 500
    t = np.arange(n) / 2500.0 + 3.0
    q = np.random.default_rng(1).standard_normal((n, 6))
    with McapWriter(path, _env(tmp_path), flush_period_s=0.05) as w:
        w.write_arrays(
            "/joints", t, {"q": q, "status": np.arange(n, dtype=np.int32), "tau": np.zeros((n, 6))}
        )
        w.add_channel("/event", "rxcomm.Event", {"what": {"type": "string"}, "lag_rad": vector_field(2)})
        w.add_channel("/scalar", "rxcomm.Scalar", {"x": number_field("m"), "ok": {"type": "boolean"}})
        w.write("/event", 3.01, {"what": "start", "lag_rad": np.array([0.5, np.nan])})
        w.write("/event", 3.02, {"lag_rad": [1.0, 2.0], "what": "stop"})  # key order does not matter
        for i in range(3):
            w.write("/scalar", 3.0 + i * 1e-9, {"ok": i % 2 == 0, "x": float(i)})
        with pytest.raises(ValueError, match="not in the channel schema"):
            w.write("/scalar", 4.0, {"y": 1.0})
        w.set_summary({"n_selected": 1, "underruns": 0})
    assert path.exists() and not (tmp_path / "log.mcap.part").exists()

    c = read_mcap(path)
    assert c.complete and c.envelope["kind"] == "rxcomm/Demo" and c.envelope["summary"]["underruns"] == 0
    j = c.topics["/joints"]
    assert j.schema_title == "rxcomm.joints"
    assert np.array_equal(j.q, q) and j.q.dtype == np.float64  # %.17g round-trips exactly
    assert j.tau.dtype == np.float64 and not j.tau.any()  # zeros written as "0", typed by the schema
    assert j.status.dtype.kind == "i" and np.array_equal(j.status, np.arange(n))
    assert np.max(np.abs(j.t - t)) < 1e-12
    ev = c.topics["/event"]
    assert list(ev.what) == ["start", "stop"] and np.isnan(ev.lag_rad[0, 1]) and ev.lag_rad[1, 1] == 2.0
    sc = c.topics["/scalar"]
    assert sc.ok.dtype == bool and list(sc.ok) == [True, False, True]
    assert np.array_equal(np.round(sc.t * 1e9) - 3e9, [0, 1, 2])  # ns resolution kept

    # An independent reader (the package's seeking reader) sees the Foxglove conventions.
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        counts = {
            ch.topic: summary.statistics.channel_message_counts[i] for i, ch in summary.channels.items()
        }
        # per-sample messages, and beside each all-numeric topic one column block (< 2500 samples)
        assert counts == {"/joints": n, "/event": 2, "/scalar": 3, "/columns/joints": 1, "/columns/scalar": 1}
        schema = next(s for s in summary.schemas.values() if s.name == "rxcomm.joints")
        assert schema.encoding == "jsonschema"
        props = json.loads(schema.data)["properties"]
        assert props["timestamp"]["title"] == "time" and props["q"]["maxItems"] == 6
        encodings = {ch.topic: ch.message_encoding for ch in summary.channels.values()}
        assert encodings == {"/joints": "json", "/event": "json", "/scalar": "json"} | {
            "/columns/joints": "protobuf",
            "/columns/scalar": "protobuf",
        }
        _, _, msg = next(reader.iter_messages(topics=["/joints"]))
        body = json.loads(msg.data)
        # epoch time stamps: the writer's time origin (when it opened) + the sample time
        assert (
            abs(body["timestamp"]["sec"] + body["timestamp"]["nsec"] * 1e-9 - (c.time_origin_ns / 1e9 + 3))
            < 1e-6
        )
        assert abs(c.time_origin_ns / 1e9 - time.time()) < 60 and len(body["q"]) == 6
        assert msg.log_time == c.time_origin_ns + 3 * 10**9
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(meta[ENVELOPE_RECORD]["kind"]) == "rxcomm/Demo"


def test_mcap_exception_keeps_finished_part(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with pytest.raises(RuntimeError), McapWriter(path, _env(tmp_path)) as w:
        w.write_arrays("/x", np.arange(10) * 0.1, {"v": np.arange(10.0)})
        raise RuntimeError("safety stop")
    assert not path.exists()
    with pytest.raises(InputError):
        read_mcap(tmp_path / "nothere.mcap")
    c = recover_mcap(tmp_path / "run.mcap.part")
    assert c.complete and np.array_equal(c.topics["/x"].v, np.arange(10.0))


def test_read_mcap_refuses_garbage_and_unfinished(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"this is not an mcap file at all")
    with pytest.raises(InputError, match="not an MCAP file"):
        read_mcap(junk)
    full = tmp_path / "full.mcap"
    with McapWriter(full, _env(tmp_path)) as w:
        w.write_arrays("/x", np.arange(100) * 0.01, {"v": np.arange(100.0)})
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(full.read_bytes()[:-200])
    with pytest.raises(InputError, match="incomplete MCAP") as ei:
        read_mcap(cut)
    assert ei.value.file == str(cut)


@pytest.mark.slow
def test_recover_truncated_files_at_every_cut(tmp_path: Path) -> None:
    """Cut a finished file at many offsets: recovery never raises and returns a prefix of the data."""
    full = tmp_path / "full.mcap"
    n = 3000
    t = np.arange(n) / 1000.0
    with McapWriter(full, _env(tmp_path), flush_period_s=0.25) as w:
        w.write_arrays("/x", t, {"v": np.arange(n, dtype=float), "q": np.ones((n, 6))})
    data = full.read_bytes()
    counts = []
    for cut in np.linspace(20, len(data) - 1, 60).astype(int):
        part = tmp_path / "cut.mcap.part"
        part.write_bytes(data[:cut])
        c = recover_mcap(part)
        assert not c.complete and c.stopped_because
        x = c.topics.get("/x")
        got = 0 if x is None else len(x)
        if got:
            assert c.envelope["kind"] == "rxcomm/Demo"  # the envelope is written before any data
            assert np.array_equal(x.v, np.arange(got)) and np.all(np.diff(x.t) > 0)
        counts.append(got)
    assert counts == sorted(counts) and counts[-1] >= n - 300  # a 0.25 s chunk at most is lost


_KILLED_WRITER = textwrap.dedent(
    """
    import sys, time, numpy as np
    from rxcomm.io.mcap_io import McapWriter
    from rxcomm.schemas.trajectory import TrajectorySummary
    env = TrajectorySummary.envelope({}, {}, {})
    w = McapWriter(sys.argv[1], env, flush_period_s=0.2)
    w.add_channel("/log", "rxcomm.Log", {"i": {"type": "integer"}, "q": {"type": "array"}})
    t0, i = time.monotonic(), 0
    while True:  # 2.5 kHz in real time, in batches of 25
        t = time.monotonic() - t0
        while i < t * 2500:
            w.write("/log", i / 2500, {"i": i, "q": [i * 1e-3] * 6})
            i += 1
        print(i, flush=True)
        time.sleep(0.01)
    """
)


@pytest.mark.process
def test_kill_minus_9_and_recover(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    part = tmp_path / "run-log.mcap.part"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(tmp_path / "run-log.mcap")],
        stdout=subprocess.PIPE,
        text=True,
    )
    guard = threading.Timer(20.0, proc.kill)  # bound the test whatever happens
    guard.start()
    try:
        written = 0
        while written < 2500 * 1.2:  # ~1.2 s of data
            line = proc.stdout.readline()
            assert line, "writer died"
            written = int(line)
        proc.kill()  # SIGKILL: no finish(), no footer
        proc.wait(timeout=10)
    finally:
        guard.cancel()
        proc.stdout.close()
    assert proc.returncode == -9 and part.exists()
    with pytest.raises(InputError, match="incomplete"):
        read_mcap(part)
    out = tmp_path / "run-log.mcap"
    c = recover_mcap(part, out)
    log = c.topics["/log"]
    fraction = len(log) / written
    with capsys.disabled():
        print(
            f"\nkill -9 after {written} messages: recovered {len(log)} ({fraction:.0%}), {c.stopped_because}"
        )
    assert np.array_equal(log.i, np.arange(len(log))) and np.all(np.diff(log.t) > 0)
    assert fraction > 0.5 and written - len(log) <= 2500 * 0.3 + 100  # ≤ one 0.2 s flush period + a batch
    again = read_mcap(out)
    assert again.complete and np.array_equal(again.topics["/log"].q, log.q)
    assert again.envelope["kind"] == "rxcomm/Trajectory"
    assert json.loads(again.metadata[RECOVERED_RECORD]["complete"]) is False


def _bulk(tmp_path: Path, n: int, digits: int = 17) -> tuple[float, float, int]:
    t = np.arange(n) / 2500.0
    rng = np.random.default_rng(0)
    cols = {k: rng.standard_normal((n, 6)) for k in ("q", "qd", "qdd", "tau_ff")}
    path = tmp_path / f"bulk{n}.mcap"
    t0 = time.perf_counter()
    with McapWriter(path, _env(tmp_path)) as w:
        w.write_arrays("/trajectory", t, cols, digits=digits)
    t1 = time.perf_counter()
    c = read_mcap(path)
    t2 = time.perf_counter()
    assert len(c.topics["/trajectory"]) == n
    if digits == 17:
        assert np.array_equal(c.topics["/trajectory"].qdd, cols["qdd"])
    return t1 - t0, t2 - t1, path.stat().st_size


@pytest.mark.slow  # a timing printout: it belongs with the 150k run, out of the unit tier
def test_bulk_write_speed_printed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    n = 15_000  # 6 s at 2.5 kHz; the slow test below does the full 60 s
    w, r, size = _bulk(tmp_path, n)
    with capsys.disabled():
        print(
            f"\nwrite_arrays {n} msgs x 4x6 floats: write {w:.2f} s ({w / n * 1e6:.0f} us/msg, "
            f"150k ~ {w / n * 150e3:.1f} s), read {r:.2f} s, {size / n:.0f} B/msg"
        )


@pytest.mark.slow
def test_bulk_write_150k(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    for digits in (17, 9):
        w, r, size = _bulk(tmp_path, 150_000, digits)
        with capsys.disabled():
            print(f"\n150k msgs, {digits} digits: write {w:.2f} s, read {r:.2f} s, {size / 1e6:.1f} MB")


# ---------------------------------------------------------------- trajectories


def _traj(n: int = 400) -> Trajectory:
    t = np.linspace(0.0, 1.0, n)
    s = 0.5 - 0.5 * np.cos(np.pi * t)
    sd = 0.5 * np.pi * np.sin(np.pi * t)
    sdd = 0.5 * np.pi**2 * np.cos(np.pi * t)
    dq = np.array([0.5, -0.3, 0.8, 1.0, -1.2, 2.0])
    return Trajectory(
        t, s[:, None] * dq, sd[:, None] * dq, sdd[:, None] * dq, extra={"sigma": s, "sigma_dot": sd}
    )


def _traj_envelope(tmp_path: Path, **summary: object) -> dict:
    path = tmp_path / "path.yaml"
    path.write_text("line: 1\n")
    base = {"duration_s": 1.0, "solve_seconds": 0.2, "max_limit_ratio": 0.98, "active_fraction": 0.6}
    base |= {"q_start": [0.0] * 6, "q_goal": [0.5, -0.3, 0.8, 1.0, -1.2, 2.0]}
    return TrajectorySummary.envelope({"path": path}, {"intervals": 400}, {**base, **summary})


def test_trajectory_mcap_round_trip_and_summary_yaml(tmp_path: Path) -> None:
    traj = _traj()
    out = tmp_path / "cp.mcap"
    names = [f"joint_{j + 1}" for j in range(6)]
    summary = save_trajectory_mcap(out, traj, _traj_envelope(tmp_path), names)
    assert sorted(os.listdir(tmp_path)) == ["cp.mcap", "cp.yaml", "path.yaml"]
    td = read_mcap(out).topics["/trajectory"]
    assert td.constants == {"joint_names": names} and "joint_names" not in td.fields
    with open(out, "rb") as f:  # in every message Foxglove shows, epoch-stamped from the plan's creation
        _, _, msg = next(make_reader(f).iter_messages(topics=["/trajectory"]))
    body = json.loads(msg.data)
    assert body["joint_names"] == names and abs(body["timestamp"]["sec"] - time.time()) < 600
    back, env = load_trajectory_mcap(out)
    assert np.max(np.abs(back.t - traj.t)) <= 0.5e-9  # MCAP log times have ns resolution
    for name in ("q", "qd", "qdd", "tau_ff"):
        assert np.array_equal(getattr(back, name), getattr(traj, name)), name
    assert np.array_equal(back.extra["sigma_dot"], traj.extra["sigma_dot"]) and not back.tau_ff.any()
    assert env["summary"]["max_limit_ratio"] == 0.98 and env["settings"] == {"intervals": 400}
    side = read_yaml_artefact(tmp_path / "cp.yaml", TrajectorySummary)
    assert side == summary and side.mcap_sha256 == sha256_file(out) and side.n_samples == 400
    assert side.fields == ["q", "qd", "qdd", "tau_ff", "sigma", "sigma_dot"]
    assert side.created.isoformat().replace("+00:00", "Z") == env["created"]


def test_trajectory_file_refusals(tmp_path: Path) -> None:
    other = tmp_path / "log.mcap"
    with McapWriter(other, _env(tmp_path)) as w:
        w.write_arrays("/trajectory", np.arange(3.0), {"q": np.zeros((3, 6))})
    with pytest.raises(InputError) as ei:
        load_trajectory_mcap(other)
    assert (ei.value.file, ei.value.field) == (str(other), "envelope.kind")
    no_qd = tmp_path / "noqd.mcap"
    with McapWriter(no_qd, _traj_envelope(tmp_path)) as w:
        w.write_arrays("/trajectory", np.arange(3.0), {"q": np.zeros((3, 6)), "qdd": np.zeros((3, 6))})
    with pytest.raises(InputError) as ei:
        load_trajectory_mcap(no_qd)
    assert ei.value.field == "/trajectory.qd"
    with pytest.raises(InputError, match="must end in .mcap"):
        save_trajectory_mcap(tmp_path / "cp.yaml", _traj(), _traj_envelope(tmp_path))
    env = _traj_envelope(tmp_path)
    del env["summary"]["q_goal"]
    with pytest.raises(ValidationError, match="q_goal"):
        save_trajectory_mcap(tmp_path / "x.mcap", _traj(), env)
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "x.mcap.part").exists()


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda a: a["t"].__setitem__(5, a["t"][4]), "t"),
        (lambda a: a.update(qd=a["qd"][:, :5]), "qd"),
        (lambda a: a["qdd"].__setitem__((7, 2), np.inf), "qdd"),
        (lambda a: a.update(extra={"sigma": np.zeros(3)}), "sigma"),
        (lambda a: a.update(extra={"q": np.zeros(10)}), "q"),
    ],
)
def test_trajectory_validation(change, field: str) -> None:
    n = 10
    a = {"t": np.arange(n) * 0.1, "q": np.zeros((n, 6)), "qd": np.zeros((n, 6)), "qdd": np.zeros((n, 6))}
    change(a)
    with pytest.raises(InvalidTrajectory) as ei:
        Trajectory(**a)
    assert ei.value.field == field


def test_trajectory_is_immutable_copy() -> None:
    q = np.zeros((3, 6))
    tr = Trajectory(np.arange(3.0), q, q, q)
    q[0, 0] = 1.0  # the caller's array is not shared
    assert tr.q[0, 0] == 0.0 and tr.dof == 6 and tr.duration_s == 2.0
    with pytest.raises(ValueError):
        tr.q[0, 0] = 2.0


def test_write_summary_yaml_beside_log(tmp_path: Path) -> None:
    art = _demo(tmp_path)
    assert write_summary_yaml(tmp_path / "run-log.mcap", art) == tmp_path / "run-log.yaml"
    assert read_yaml_artefact(tmp_path / "run-log.yaml", Demo) == art


def test_column_blocks_equal_the_messages_nan_rows_and_blocks_of_2500(tmp_path: Path) -> None:
    """The reader's blocks give what the per-sample JSON gives: NaN (null) rows from write(), integer and
    boolean columns, more samples than one block holds."""
    path = tmp_path / "mixed.mcap"
    n = 6000  # three blocks
    t = np.arange(n) / 2500.0
    q = np.random.default_rng(3).standard_normal((n, 6))
    with McapWriter(path, _env(tmp_path), flush_period_s=0.3) as w:
        w.write_arrays("/a", t, {"q": q, "k": np.arange(n)}, digits=17)
        w.add_channel("/b", "rxcomm.B", {"x": number_field("m"), "ok": {"type": "boolean"}})
        for i in range(50):
            w.write("/b", i * 0.01, {"x": float("nan") if i % 7 == 0 else i * 0.5, "ok": i % 2 == 0})
    fast = read_mcap(path)
    slow = read_mcap(path, columns=False)
    for topic in ("/a", "/b"):
        a, b = fast.topics[topic], slow.topics[topic]
        assert np.array_equal(a.t, b.t) and set(a.fields) == set(b.fields)
        for k in a.fields:
            assert a[k].dtype == b[k].dtype and np.array_equal(
                a[k], b[k], equal_nan=a[k].dtype.kind == "f"
            ), k
    assert np.isnan(fast.topics["/b"].x[::7]).all() and fast.topics["/b"].ok.dtype == bool
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
        blocks = next(
            s.statistics.channel_message_counts[i] for i, c in s.channels.items() if c.topic == "/columns/a"
        )
        columns = {i for i, c in s.channels.items() if c.topic.startswith("/columns/")}
        for ci in s.chunk_indexes:  # blocks in chunks of their own, uncompressed; the JSON in zstd chunks
            ids = set(ci.message_index_offsets)
            assert (ids <= columns and ci.compression == "") or (
                not ids & columns and ci.compression == "zstd"
            )
    assert blocks >= 3


def test_a_log_from_before_the_time_origin_and_columns_still_reads(tmp_path: Path) -> None:
    """A run log as rxcomm wrote it before (no rxcomm/time record, no column channel, no tcp_speed_m_s):
    identify's fields read, t from 0; the default reader refuses it naming the missing field."""
    from mcap.writer import Writer

    from rxcomm.io.mcap_format import encode_metadata, envelope_values
    from rxcomm.io.run_log import read_run_log
    from rxcomm.schemas.run_log import RunLog

    path = tmp_path / "old.mcap"
    env = RunLog.envelope({}, {}, {"underruns": 0, "max_lag_rad": [0.0] * 6, "rms_lag_rad": [0.0] * 6,
                                   "max_tcp_error_m": 0.0, "duration_s": 0.4})  # fmt: skip
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="rxcomm")
        w.add_metadata("rxcomm/envelope", encode_metadata(envelope_values(env)))
        vec = {"type": "array", "items": {"type": "number"}}
        props = {"q_actual": vec, "tau_actual": vec}
        sid = w.register_schema("rxcomm.RunJoints", "jsonschema", json.dumps({"properties": props}).encode())
        cid = w.register_channel("/run/joints", "json", sid)
        for i in range(1001):
            body = {
                "timestamp": {"sec": 0, "nsec": i * 400_000},
                "q_actual": [i * 1e-3] * 6,
                "tau_actual": [1] * 6,
            }
            w.add_message(cid, i * 400_000, json.dumps(body).encode(), i * 400_000)
        w.finish()
    log = read_run_log(path, fields=("q_actual", "tau_actual"))
    assert log.joints.t[0] == 0.0 and abs(log.joints.t[-1] - 0.4) < 1e-12
    assert log.joints.tau_actual.dtype == np.float64 and log.joints.q_actual[-1, 0] == 1.0
    with pytest.raises(InputError) as ei:
        read_run_log(path)
    assert ei.value.field == "/run/joints.q_demand"  # the first field of the contract it lacks
