"""Run logs in the row layout (issue 32): one protobuf message per sample, the copy Foxglove plots and
rxcomm reads, its values on the fields' grids (``log_grid``); the layouts before (float32 rows without
the grids, per-sample JSON + column blocks) still read with the same figures, both as today's writer
writes them and as the old code wrote them (the fixtures in tests/data/run-logs-before)."""

from __future__ import annotations

import json
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

import rxcomm
from bench.logs import synthetic_result
from rxcomm.errors import InputError
from rxcomm.execution.frames import link_transforms, link_tree
from rxcomm.execution.log import LAYOUTS, recover_run_log, write_run_log
from rxcomm.execution.log_grid import joint_grid_steps, on_grid
from rxcomm.execution.summary import tcp_error_and_speed
from rxcomm.io.mcap_io import McapWriter, read_mcap
from rxcomm.io.mcap_rows import check_rows, row_fields, row_header
from rxcomm.io.run_log import read_run_log
from rxcomm.model.batch_kinematics import serial_chain, tcp_positions, tcp_positions_pinocchio
from rxcomm.schemas.run_log import GATEWAY_TOPIC, JOINT_FIELDS, JOINTS_TOPIC

DURATION_S = 4.0
BEFORE = Path(__file__).parent / "data" / "run-logs-before"  # written by the code before the grids


def _env() -> dict:
    return {
        "kind": "rxcomm/Test",
        "schema_version": 1,
        "created": datetime.now(UTC),
        "rxcomm_version": rxcomm.__version__,
        "inputs": {},
        "settings": {},
        "summary": {},
    }


@pytest.fixture(scope="module")
def logs(tmp_path_factory, rx130l) -> dict[str, Path]:
    """The same synthetic 4 s stream (2.5 kHz, actual values in register units) in every layout."""
    tmp = tmp_path_factory.mktemp("layouts")
    result = synthetic_result(DURATION_S, rx130l.tau_cont)
    out = {}
    for layout in LAYOUTS:
        path = tmp / f"{layout}.mcap"
        write_run_log(
            path,
            rx130l,
            result,
            inputs={},
            settings={},
            feedforward="prior",
            embedded_cell=True,
            layout=layout,
        )
        out[layout] = path
    return out


def _figures(path: Path) -> dict[str, np.ndarray]:
    """What rxcomm takes from a run log: the following error's RMS and peak per joint, the TCP error's
    peak, the torque RMS, the time span, the gateway's lead."""
    log = read_run_log(path)
    j = log.joints
    assert log.gateway is not None
    return {
        "rms_lag_rad": np.sqrt(np.mean(j.following_error**2, axis=0)),
        "max_lag_rad": np.max(np.abs(j.following_error), axis=0),
        "max_tcp_error_m": np.max(j.tcp_error_m),
        "rms_tau_nm": np.sqrt(np.mean(j.tau_actual**2, axis=0)),
        "duration_s": j.t[-1] - j.t[0],
        "min_lead_s": np.min(log.gateway.lead_s),
    }


def _assert_same_figures(old_path: Path, new_path: Path) -> None:
    """Every field of ``/run/joints`` within half its grid step (+ float32 rounding of the old rows),
    the gateway and the time stamps exact, the figures rxcomm takes within what the grids allow, the
    summary's figures equal (the writer computes them from the float64 records)."""
    old, new = read_run_log(old_path), read_run_log(new_path)
    assert len(new.joints) == len(old.joints) > 0
    np.testing.assert_array_equal(new.joints.t, old.joints.t)
    assert new.joints.constants == old.joints.constants
    assert set(new.joints.fields) == set(old.joints.fields) == set(JOINT_FIELDS)
    step = joint_grid_steps()
    for k, v in old.joints.fields.items():
        assert new.joints[k].dtype == np.float64
        tol = step[k] / 2 + 2 * np.spacing(np.abs(v).astype(np.float32)).astype(float)
        assert np.all(np.abs(new.joints[k] - v) <= tol), k
    assert old.gateway is not None and new.gateway is not None
    for k, v in old.gateway.fields.items():  # counters and times exact
        np.testing.assert_array_equal(new.gateway[k], v, err_msg=k)
    a, b = _figures(old_path), _figures(new_path)
    atol = {"rms_lag_rad": step["following_error"], "max_lag_rad": step["following_error"]}
    atol |= {"max_tcp_error_m": step["tcp_error_m"], "rms_tau_nm": step["tau_actual"]}
    for k in a:
        np.testing.assert_allclose(b[k], a[k], rtol=1.2e-7, atol=atol.get(k, 0.0), err_msg=k)
    both = set(old.summary) & set(new.summary)  # a figure added later is not in the old summary
    assert len(both) > 10 and {k: new.summary[k] for k in both} == {k: old.summary[k] for k in both}


@pytest.mark.parametrize("before", ["rows-float32", "json-columns"])
def test_the_layouts_before_read_with_the_same_figures(logs, before):
    _assert_same_figures(logs[before], logs["rows"])


@pytest.mark.parametrize("layout", ["rows", "json-columns"])
def test_logs_written_by_the_old_code_read_with_the_same_figures(tmp_path, rx130l, layout):
    """The fixtures were written by the writer before the grids (make.py there, from main d1f9a8e):
    today's reader reads them, and the same stream written today reads with the same figures."""
    old = BEFORE / f"{layout}.mcap"
    duration = 0.1  # make.py's DURATION_S: 251 samples
    assert len(read_run_log(old).joints) == 251
    now = tmp_path / "now.mcap"
    write_run_log(
        now,
        rx130l,
        synthetic_result(duration, rx130l.tau_cont),
        inputs={},
        settings={},
        feedforward="prior",
        embedded_cell=True,
    )
    _assert_same_figures(old, now)


def test_a_log_off_by_more_than_its_grid_is_not_the_same(tmp_path, rx130l):
    """The comparison fails on a log whose encoders read 1 µrad more (two grid steps)."""
    result = synthetic_result(0.1, rx130l.tau_cont)
    paths = []
    for name, shift in (("a", 0.0), ("b", 1e-6)):
        assert result.log is not None
        log = replace(result.log, q_actual=result.log.q_actual + shift)
        paths.append(tmp_path / f"{name}.mcap")
        write_run_log(
            paths[-1],
            rx130l,
            replace(result, log=log),
            inputs={},
            settings={},
            feedforward="prior",
            embedded_cell=True,
        )
    _assert_same_figures(paths[0], paths[0])
    with pytest.raises(AssertionError, match="q_actual"):
        _assert_same_figures(paths[0], paths[1])


def test_the_grids_cut_the_joint_messages_and_the_views(logs):
    """On the same stream: the grids and the views' fixed point make the file ≥ 15 % smaller than the
    float32 rows, which were a third of the layout before issue 32 or less."""
    size = {k: v.stat().st_size for k, v in logs.items()}
    assert size["rows-float32"] < size["json-columns"] / 3, size
    assert size["rows"] < 0.85 * size["rows-float32"], size


def test_the_mcap_reader_decodes_every_message_with_its_protobuf_schema(logs):
    """The mcap package (CRCs checked) and its protobuf decoder read the file as Foxglove would: the
    schema is a valid FileDescriptorSet and every message decodes to rxcomm's values."""
    log = read_run_log(logs["rows"])
    got: dict[str, list] = {JOINTS_TOPIC: [], GATEWAY_TOPIC: []}
    with open(logs["rows"], "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()], validate_crcs=True)
        for schema, channel, _, msg in reader.iter_decoded_messages(topics=list(got)):
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
            got[channel.topic].append(msg)
    assert len(got[JOINTS_TOPIC]) == len(log.joints) and len(got[GATEWAY_TOPIC]) == len(log.gateway)
    for i in (0, 1234, len(log.joints) - 1):
        m = got[JOINTS_TOPIC][i]
        np.testing.assert_array_equal(np.array(m.q_actual), log.joints.q_actual[i])
        np.testing.assert_array_equal(np.array(m.following_error), log.joints.following_error[i])
        assert m.tcp_speed_m_s == log.joints.tcp_speed_m_s[i]
    assert [m.execute_index for m in got[GATEWAY_TOPIC]] == log.gateway.execute_index.tolist()


def test_every_message_of_the_new_log_decodes_with_the_schemas_in_the_file(logs):
    """The mcap package's reader (CRCs checked) with nothing but the file: every protobuf message
    decodes with its channel's FileDescriptorSet, every JSON message parses and has its schema's
    properties (Foxglove's well-known schemas for the views), and the counts are the summary's."""
    decoder = DecoderFactory()
    counts: dict[str, int] = {}
    with open(logs["rows"], "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            if channel.message_encoding == "protobuf":
                decode = decoder.decoder_for(channel.message_encoding, schema)
                assert decode is not None
                body = decode(message.data)
                assert body.ListFields(), channel.topic  # every row field is always written
            else:
                assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
                props = json.loads(schema.data)["properties"]
                assert set(json.loads(message.data)) == set(props), channel.topic
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
    expected = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts == expected and counts[JOINTS_TOPIC] == int(DURATION_S * 2500) + 1
    assert {"/run/tf", "/run/tf_demand", "/run/tcp", "/run/tcp_demand", GATEWAY_TOPIC} <= set(counts)


def test_a_message_of_another_layout_is_refused(tmp_path):
    rows = row_fields({"a": ("<f4", 3), "b": ("<i8", 0)})
    good = row_header(rows, 4)
    check_rows(good, rows)
    bad = good.copy()
    bad["_len1"][2] = 8  # two floats claimed where the schema has three
    with pytest.raises(ValueError, match="_len1"):
        check_rows(bad, rows)
    with pytest.raises(ValueError, match="1..15 fields"):
        row_fields({f"f{i}": ("<f8", 0) for i in range(16)})
    with pytest.raises(ValueError, match="dtype"):
        row_fields({"x": ("<f2", 0)})
    path = tmp_path / "bad.mcap"  # a file whose row bytes were damaged: the reader names the topic
    env = _env()
    with McapWriter(path, env, compression="none") as w:
        w.add_row_channel("/x", "rxcomm.X", {"a": ("<f4", 3)})
        w.write_arrays("/x", np.arange(3) * 0.1, {"a": np.ones((3, 3))})
    data = bytearray(path.read_bytes())
    marker = bytes(row_header(row_fields({"a": ("<f4", 3)}), 1).tobytes()[:2])  # tag, length
    i = data.index(marker + np.ones(3, dtype="<f4").tobytes())
    data[i + 1] = 8
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="CRC mismatch"):  # the chunk CRC catches it first
        read_mcap(path)


def test_rows_mixed_with_other_messages_and_a_recovered_log_read_alike(logs, tmp_path):
    """A row channel written message by message between other channels (a chunk of mixed records),
    and a killed run's .part recovered, give the rows the fast path gives."""
    env = _env()
    path = tmp_path / "mixed.mcap"
    values = np.arange(12.0).reshape(4, 3)
    with McapWriter(path, env) as w:
        w.add_row_channel("/x", "rxcomm.X", {"a": ("<f8", 3)})
        w.add_channel("/y", "rxcomm.Y", {"b": {"type": "number"}})
        for i in range(4):
            w.write("/x", 0.1 * i, {"a": values[i]})
            w.write("/y", 0.1 * i + 0.05, {"b": float(i)})
    td = read_mcap(path).topics["/x"]
    np.testing.assert_array_equal(td.a, values)
    np.testing.assert_allclose(td.t, 0.1 * np.arange(4))
    # a killed writer: cut the finished log inside its last chunks, recover, read the rows back
    part = tmp_path / "cut.mcap.part"
    data = logs["rows"].read_bytes()
    part.write_bytes(data[: len(data) * 2 // 3])
    rec = recover_run_log(part, tmp_path / "cut.recovered.mcap")
    back = read_run_log(rec.written)
    full = read_run_log(logs["rows"])
    n = len(back.joints)
    assert 0 < n < len(full.joints) and rec.n_records == n
    np.testing.assert_array_equal(back.joints.q_actual, full.joints.q_actual[:n])


def test_batch_forward_kinematics_equals_pinocchio(robot):
    """The writer's numpy FK (TCP position and J_v·qd) against Pinocchio, on both sample robots."""
    chain = serial_chain(robot)
    assert chain is not None
    rng = np.random.default_rng(7)
    q = rng.uniform(-2.5, 2.5, (300, robot.n))
    qd = rng.uniform(-2.0, 2.0, (300, robot.n))
    p, v = tcp_positions(chain, q, qd)
    np.testing.assert_allclose(p, tcp_positions_pinocchio(robot, q), atol=1e-12)
    # velocity by finite differences of the Pinocchio positions along qd
    h = 1e-6
    fd = (tcp_positions_pinocchio(robot, q + h * qd) - tcp_positions_pinocchio(robot, q - h * qd)) / (2 * h)
    np.testing.assert_allclose(v, fd, atol=1e-7)
    err, speed = tcp_error_and_speed(robot, q, qd, q + 1e-3)
    assert np.all(err > 0) and np.allclose(speed, np.linalg.norm(fd, axis=1), atol=1e-7)


def test_row_channel_metadata_names_the_fields(logs):
    with open(logs["rows"], "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    ch = next(c for c in summary.channels.values() if c.topic == JOINTS_TOPIC)
    rows = json.loads(ch.metadata["rxcomm/rows"])
    assert [r[0] for r in rows] == list(JOINT_FIELDS) and rows[0][1:] == ["<f4", 6]
    assert json.loads(ch.metadata["rxcomm/grid"]) == joint_grid_steps()
    assert not any(c.topic.startswith("/columns/") for c in summary.channels.values())


def _views(path: Path, topic: str) -> np.ndarray:
    """Every number of every ``topic`` message (FrameTransforms or PoseInFrame JSON), in file order."""
    with open(path, "rb") as f:
        msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]

    def numbers(x):
        if isinstance(x, dict):
            return [v for k, y in x.items() if k != "timestamp" for v in numbers(y)]
        if isinstance(x, list):
            return [v for y in x for v in numbers(y)]
        return [x] if isinstance(x, float | int) and not isinstance(x, bool) else []

    return np.array([numbers(m) for m in msgs], dtype=float)


@pytest.mark.parametrize("topic", ["/run/tf", "/run/tf_demand", "/run/tcp", "/run/tcp_demand"])
def test_the_views_keep_the_frames_to_a_micrometre(logs, rx130l, topic):
    """The 3D views in fixed point (6 decimals: 1 µm, 1e-6 of a quaternion component) against the same
    views with every digit (the float32 rows' writer): no value moves by more than the rounding."""
    full, fixed = _views(logs["rows-float32"], topic), _views(logs["rows"], topic)
    assert fixed.shape == full.shape and fixed.shape[0] > 100
    assert np.max(np.abs(fixed - full)) <= 5e-7 + 1e-15
    assert np.array_equal(np.round(fixed, 6), fixed) and not np.array_equal(np.round(full, 6), full)
    if topic == "/run/tf":  # the full views are the FK of the logged encoders (sample 0)
        trans, rot = link_transforms(
            rx130l, link_tree(rx130l), read_run_log(logs["rows-float32"]).joints.q_actual[0]
        )
        np.testing.assert_allclose(full[0], np.concatenate([trans[0], rot[0]], axis=1).ravel(), atol=1e-6)


def test_the_logged_joints_are_on_their_grids_and_a_lost_record_stays_lost(logs):
    """Every value read back is a whole number of its field's grid steps (float32 holds them exactly),
    and rounding keeps NaN (a record the gateway lost) and the grid values themselves."""
    j = read_run_log(logs["rows"]).joints
    for k, step in joint_grid_steps().items():
        units = j[k] / step
        assert np.array_equal(units, np.round(units)), k
    x = np.array([[np.nan, 0.1, -3.0000001], [1e-9, 2.0**-22, 7.9]])
    g = on_grid({"q_actual": x, "tau_actual": x, "other": x})
    assert np.isnan(g["q_actual"][0, 0]) and g["other"] is x  # fields without a grid pass unchanged
    np.testing.assert_array_equal(on_grid(g)["q_actual"], g["q_actual"])
    assert np.all(np.abs(g["q_actual"] - x)[~np.isnan(x)] <= 2.0**-22)
    assert np.array_equal(g["q_actual"].astype(np.float32).astype(float), g["q_actual"], equal_nan=True)
