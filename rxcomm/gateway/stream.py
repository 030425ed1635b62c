"""Stream a sampled trajectory through a gateway and collect the complete trace.

The master side of the streaming handshake in docs/gateway.md: clear, prefill, stream enable, keep
up to ``high_level`` cycles buffered (a deep buffer rides out scheduling hiccups of the master; the
trajectory is planned ahead, so depth costs nothing but stop latency), mark the last block
end-of-stream, then
poll until the gateway reports done and every trace record has arrived. Any stop (underrun, fault,
watchdog, e-stop, quick stop) raises SafetyStop with what the gateway reported.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from rxcomm.errors import GatewayError, InputError, SafetyStop
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.client import BlockReply, GatewayClient

PROGRESS_TIMEOUT_S = 10.0  # a stream still executing setpoints is not timed out before this without any
STOP_BITS = R.Status.UNDERRUN | R.Status.WATCHDOG | R.Status.ESTOP | R.Status.AXIS_FAULT | R.Status.QUICK_STOP


@dataclass(frozen=True)
class StreamResult:
    position_rad: np.ndarray  # (m, 6) trace: position actual per record
    torque_nm: np.ndarray  # (m, 6) trace: torque actual per record
    lost_records: int
    blocks: int
    busy_replies: int
    max_level: int
    final: codec.StreamStatus


def check_stop(status: codec.StreamStatus | codec.GatewayStatus) -> None:
    """SafetyStop if the gateway reports a stop condition."""
    bad = status.status & STOP_BITS
    if bad:
        raise SafetyStop(
            f"gateway stopped the stream: {bad!r}, error {status.error:#06x}, "
            f"executed {status.execute_index} of {status.write_index}"
        )


def stream(
    client: GatewayClient,
    pos_rad: np.ndarray,
    tau_ff_nm: np.ndarray,
    *,
    high_level: int = 1500,
    timeout_s: float | None = None,
    on_reply: Callable[[BlockReply], None] | None = None,
    keep_trace: bool = True,
) -> StreamResult:
    """Stream ``pos_rad``/``tau_ff_nm`` (n, 6) as setpoints 0..n-1 with the client's configured
    prefill, interpolation ratio and trace decimation (``client.configure`` first). Drives must be
    enabled. Returns the trace of the whole stream (empty with ``keep_trace=False``: an ``on_reply``
    that records it keeps the only copy). Ctrl-C sends a quick stop before re-raising
    (if that fails too, the gateway's watchdog stops the drives)."""
    pos = np.asarray(pos_rad, dtype=float)
    tau = np.asarray(tau_ff_nm, dtype=float)
    n = pos.shape[0]
    if pos.ndim != 2 or pos.shape[1] != R.N_AXES or tau.shape != pos.shape or n == 0:
        raise InputError(f"setpoints must be (n, {R.N_AXES}) with n > 0, got {pos.shape} and {tau.shape}")
    if timeout_s is None:
        timeout_s = 10.0 + 3.0 * n * client.ratio * R.CYCLE_US * 1e-6
    try:
        return _handshake(client, pos, tau, timeout_s, high_level, on_reply, keep_trace)
    except KeyboardInterrupt:
        with contextlib.suppress(GatewayError):
            client.quick_stop()
        raise


def _handshake(
    client: GatewayClient,
    pos: np.ndarray,
    tau: np.ndarray,
    timeout_s: float,
    high_level: int,
    on_reply: Callable[[BlockReply], None] | None,
    keep_trace: bool,
) -> StreamResult:
    """The streaming handshake for checked (n, 6) setpoints, until done; it times out ``timeout_s``
    after the start, a deadline put off to ``PROGRESS_TIMEOUT_S`` after each reply showing the gateway
    executed more setpoints (a virtual-time cell on a loaded machine runs slower than its stream time: a
    deadline from the start alone stopped `make commission` at 57 % of a 4.2 s plan, still moving)."""
    n = pos.shape[0]
    progress_at = time.monotonic()
    deadline = progress_at + timeout_s
    executed = 0
    cycle_s = R.CYCLE_US * 1e-6
    expected = n * client.ratio // client.decimation
    k = R.MAX_CYCLES_PER_BLOCK
    positions: list[np.ndarray] = []
    torques: list[np.ndarray] = []
    lost = blocks = busy = max_level = 0

    def take(reply: BlockReply) -> codec.StreamStatus:
        nonlocal lost, max_level, deadline, executed, progress_at
        if on_reply is not None:
            on_reply(reply)
        if keep_trace:
            positions.append(reply.trace.position_rad)
            torques.append(reply.trace.torque_nm)
        lost += reply.trace.lost
        assert reply.status is not None
        max_level = max(max_level, reply.status.buffer_level)
        if reply.status.execute_index > executed:  # progress: the timeout counts from here
            executed, progress_at = reply.status.execute_index, time.monotonic()
            deadline = max(deadline, progress_at + PROGRESS_TIMEOUT_S)
        return reply.status

    client.clear_stream()
    i = 0
    started = False
    status: codec.StreamStatus | None = None
    while i < n:
        if time.monotonic() > deadline:
            raise GatewayError(
                f"stream timed out at setpoint {i} of {n} "
                f"(nothing executed for {time.monotonic() - progress_at:.1f} s)"
            )
        if not started and i >= min(max(client.prefill, 1), n):
            client.start_stream()
            started = True
        if started and status is not None and status.buffer_level >= high_level:
            time.sleep(max(0.0005, (status.buffer_level - high_level) * cycle_s * client.ratio))
            status = take(client.poll())
            check_stop(status)
            continue
        j = min(i + k, n)
        try:
            reply = client.write_block(i, pos[i:j], tau[i:j], end_of_stream=(j == n))
        except GatewayError:
            check_stop(client.status())  # a refused block after a stop: report the stop
            raise
        if not reply.accepted:
            busy += 1
            time.sleep(k * cycle_s * client.ratio)
            continue
        blocks += 1
        status = take(reply)
        check_stop(status)
        i = j
    if not started:
        client.start_stream()
    while True:
        assert status is not None
        if status.status & R.Status.DONE and client.trace_next >= expected:
            break
        if time.monotonic() > deadline:
            raise GatewayError(
                f"stream not done in time: {status}, {client.trace_next}/{expected} trace records "
                f"(nothing executed for {time.monotonic() - progress_at:.1f} s)"
            )
        status = take(client.poll())
        check_stop(status)
        if status.buffer_level > R.MAX_RECORDS_PER_WINDOW:  # records come no faster than cycles run
            time.sleep(cycle_s)
    return StreamResult(
        position_rad=np.concatenate(positions) if positions else np.zeros((0, R.N_AXES)),
        torque_nm=np.concatenate(torques) if torques else np.zeros((0, R.N_AXES)),
        lost_records=lost,
        blocks=blocks,
        busy_replies=busy,
        max_level=max_level,
        final=status,
    )
