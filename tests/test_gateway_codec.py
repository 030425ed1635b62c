"""Register map v1 codec: word order, scaling, block layouts (no sockets)."""

from __future__ import annotations

import numpy as np
import pytest

from rxcomm.errors import GatewayError, InputError
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R


def test_map_sizes_match_design_table():
    # docs/gateway.md: block 1000-1112, window 2000-2116, both inside one FC23 (write ≤ 121, read ≤ 125).
    assert R.BLOCK_BASE + R.BLOCK_MAX_WORDS - 1 == 1112
    assert R.WINDOW_BASE + R.WINDOW_WORDS - 1 == 2116
    assert R.BLOCK_MAX_WORDS <= 121 and R.WINDOW_WORDS <= 125
    assert R.axis_base(5) + R.AXIS_STRIDE - 1 == 219
    spans = sorted((b, b + n) for _, b, n, _ in R.sections())
    assert all(e1 <= b2 for (_, e1), (b2, _) in zip(spans, spans[1:], strict=False))


def test_32_bit_values_are_high_word_first():
    assert codec.to_words("i", 0x12345678) == [0x1234, 0x5678]
    assert codec.to_words("i", -2) == [0xFFFF, 0xFFFE]
    assert codec.from_words("i", [0xFFFF, 0xFFFE]) == (-2,)
    assert codec.to_words("h", -1) == [0xFFFF]


def test_out_of_range_is_input_error():
    with pytest.raises(InputError):
        codec.to_words("h", 40000)
    big = np.full((1, 6), 2**31)
    with pytest.raises(InputError):
        codec.encode_block(codec.SetpointBlock(0, 0, 0, big, np.zeros((1, 6), int)))


def test_block_round_trip_and_layout():
    rng = np.random.default_rng(1)
    pos = rng.integers(-(2**31), 2**31, size=(6, 6))
    tq = rng.integers(-(2**15), 2**15, size=(6, 6))
    blk = codec.SetpointBlock(70000, 0xBEEF, int(R.BlockFlags.END_OF_STREAM), pos, tq)
    words = codec.encode_block(blk)
    assert len(words) == R.BLOCK_MAX_WORDS
    assert words[:5] == [1, 70000 - 65536, 6, 0xBEEF, 1]
    # first axis position of cycle 0 right after the header, torques after the 6 positions
    assert codec.from_words("i", words[5:7])[0] == pos[0, 0]
    assert codec.from_words("h", words[5 + 12 : 5 + 13])[0] == tq[0, 0]
    back = codec.decode_block(words)
    assert back.first_index == 70000 and back.trace_cursor == 0xBEEF and back.count == 6
    np.testing.assert_array_equal(back.position_counts, pos)
    np.testing.assert_array_equal(back.torque_counts, tq)


def test_block_length_must_match_count():
    words = codec.encode_block(codec.SetpointBlock(0, 0, 0, np.zeros((2, 6), int), np.zeros((2, 6), int)))
    with pytest.raises(GatewayError):
        codec.decode_block(words[:-1])
    words[R.BLK_COUNT] = 7
    with pytest.raises(GatewayError):
        codec.decode_block(words)


def test_window_round_trip_saturates_actuals():
    pos = np.array([[1, -1, 2**33, -(2**33), 0, 5]] * 3)
    tq = np.array([[1, -1, 40000, -40000, 0, 7]] * 3)
    st = codec.StreamStatus(int(R.Status.STREAMING | R.Status.ALL_ENABLED), 0x8130, 12, 99, 87)
    words = codec.encode_window(st, codec.TraceRecords(65535, pos, tq))
    assert len(words) == R.WINDOW_WORDS
    st2, rec = codec.decode_window(words)
    assert st2 == st and rec.first == 65535 and rec.count == 3
    assert rec.position_counts[0, 2] == R.I32_MAX and rec.position_counts[0, 3] == R.I32_MIN
    assert rec.torque_counts[0, 2] == R.I16_MAX and rec.torque_counts[0, 3] == R.I16_MIN


def test_status_axis_tracker_identity_round_trip():
    s = codec.GatewayStatus(int(R.Status.DONE), 2**32 - 1, 5, 6, 1, 2, 0xFF01, 7, 0xABCD)
    words = codec.encode_status(s)
    assert len(words) == R.ST_COUNT and codec.decode_status(words) == s
    a = codec.AxisRegisters(0x0F, 8, 0x0237, 8, -123456, 789, -55, 0, 12, -9, 180000, 33)
    words = codec.encode_axis(a)
    assert len(words) == R.AXIS_STRIDE and codec.decode_axis(words) == a
    t = codec.TrackerWords(True, 3, np.array([1, -2, 3]), np.array([10**9, 0, -5, 7]), 42)
    words = codec.encode_tracker(t)
    assert len(words) == R.TRACKER_WORDS
    t2 = codec.decode_tracker(words)
    np.testing.assert_array_equal(t2.quaternion_counts, t.quaternion_counts)
    assert (t2.valid, t2.sequence, t2.cycle) == (True, 3, 42)
    ident = codec.Identity(R.MAGIC, 1, 6, 400, 4096, 6, -6, 8192, 1)
    words = codec.encode_identity(ident)
    assert words[6] == 0xFFFA and codec.decode_identity(words) == ident


def test_si_scaling_quantisation():
    rated = np.array([180.0, 180.0, 90.0, 30.0, 30.0, 15.0])
    q = np.array([0.1234564, -3.0, 1e-7, 2.5e-6, -2.5e-6, 6.0])
    back = codec.counts_to_rad(codec.rad_to_counts(q))
    assert np.max(np.abs(back - q)) <= 0.5e-6 + 1e-15
    tau = np.array([12.34, -179.0, 0.05, 1.0, -29.99, 14.2])
    err = codec.torque_counts_to_nm(codec.nm_to_torque_counts(tau, rated), rated) - tau
    assert np.all(np.abs(err) <= 0.5e-3 * rated + 1e-12)


@pytest.mark.parametrize(("low", "ref", "full"), [(5, 3, 5), (0xFFFF, 65536, 65535), (2, 65534, 65538)])
def test_unwrap16(low, ref, full):
    assert codec.unwrap16(low, ref) == full
