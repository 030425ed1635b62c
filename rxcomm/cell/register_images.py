"""The gateway's state machine rendered as map v1's register sections (docs/gateway.md §2).

``RegisterImages(machine).section(name, sample)`` gives the words of one whole section of
``registers.sections()``; ``GatewayCore.handle_read`` cuts a read's range out of them. Images are
computed on every read from the machine's state; the one thing kept between reads is the tracker
section, which takes a new sample only when a read starts at its first register (so a master reads
one consistent sample, however it splits the read).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rxcomm.cell.gateway_machine import GatewayMachine, Phase
from rxcomm.gateway import codec
from rxcomm.gateway import registers as R
from rxcomm.gateway.registers import ErrorCode


class RegisterImages:
    """Register images of one ``GatewayMachine``, by section name."""

    def __init__(self, machine: GatewayMachine):
        self.m = machine
        self.tracker_seq = 0  # sequence number of the last tracker sample (register 3001)
        self._tracker_words = [0] * R.TRACKER_WORDS
        self._images: dict[str, Callable[[], list[int]]] = {
            "identity": lambda: codec.encode_identity(self.identity()),
            "control": self.control,
            "status": lambda: codec.encode_status(self.gateway_status()),
            "axes": self.axes,
            "block": lambda: [0] * R.BLOCK_MAX_WORDS,  # write-only: reads as zeros
            "window": self.window,
            "sim": lambda: [int(self.m.estop_pressed), 0, 0, 0],
        }

    def section(self, name: str, sample: bool) -> list[int]:
        """Every word of section ``name``; ``sample``: the read starts at the section's first word."""
        return self.tracker(sample) if name == "tracker" else self._images[name]()

    def identity(self) -> codec.Identity:
        m = self.m
        return codec.Identity(
            magic=R.MAGIC,
            map_version=R.MAP_VERSION,
            n_axes=R.N_AXES,
            cycle_us=round(m.dt * 1e6),
            buffer_capacity=m.ring.capacity,
            max_cycles_per_block=R.MAX_CYCLES_PER_BLOCK,
            position_lsb_exponent=R.POSITION_LSB_EXPONENT,
            trace_capacity=m.trace.capacity,
            torque_lsb_permille=R.TORQUE_LSB_PERMILLE,
        )

    def control(self) -> list[int]:
        m = self.m
        return [
            m.levels,
            m.heartbeat,
            m.watchdog_ms,
            m.prefill,
            m.cursor16,
            m.ratio,
            m.decimation,
            m.cw_all,
            m.owner_token,
        ]

    def stream_status(self) -> codec.StreamStatus:
        m = self.m
        return codec.StreamStatus(
            m.status_bits(), m.error, m.ring.read_index, m.ring.write_index, m.ring.level
        )

    def gateway_status(self) -> codec.GatewayStatus:
        m = self.m
        st = self.stream_status()
        return codec.GatewayStatus(
            status=st.status,
            cycle_counter=m.cycle_counter,
            execute_index=st.execute_index,
            write_index=st.write_index,
            buffer_level=st.buffer_level,
            underrun_count=m.underrun_count,
            error=m.error,
            trace_count=m.trace.next,
            heartbeat_echo=m.heartbeat,
            stop_cause=m.stop_cause,
            overruns=m.overruns,
            clock=m.clock,
        )

    def axes(self) -> list[int]:
        m = self.m
        fb = m.fb
        pos = codec.rad_to_counts(fb.position_rad)
        vel = np.rint(fb.velocity_rad_s / R.VELOCITY_LSB_RAD_S).astype(np.int64)
        tq = codec.nm_to_torque_counts(fb.torque_nm, m.rated_nm)
        fe = codec.rad_to_counts(fb.following_error_rad)
        dem = codec.rad_to_counts(m.demand_pos)
        ff = codec.nm_to_torque_counts(m.tau_ff, m.rated_nm)
        rated = np.rint(m.rated_nm / R.RATED_TORQUE_LSB_NM).astype(np.int64)
        words: list[int] = []
        for i, d in enumerate(m.drives):
            extra = int(R.SW.FOLLOWING_ERROR) if d.error_code == ErrorCode.FOLLOWING_ERROR else 0
            words += codec.encode_axis(
                codec.AxisRegisters(
                    controlword=d.controlword,
                    mode=R.MODE_CSP,
                    statusword=d.statusword(extra),
                    mode_display=R.MODE_CSP,
                    position_counts=int(pos[i]),
                    velocity_counts=int(vel[i]),
                    torque_counts=int(tq[i]),
                    error_code=d.error_code,
                    following_error_counts=int(fe[i]),
                    position_demand_counts=int(dem[i]),
                    rated_torque_mnm=int(rated[i]),
                    torque_ff_counts=int(ff[i]),
                )
            )
        return words

    def window(self) -> list[int]:
        m = self.m
        cursor = m.trace.resolve(m.cursor16)
        records = m.trace.read(cursor, R.MAX_RECORDS_PER_WINDOW, m.rated_nm)
        return codec.encode_window(self.stream_status(), records)

    def tracker(self, sample: bool) -> list[int]:
        """The last tracker sample; a new one when ``sample`` (none while a stream runs)."""
        if not sample:
            return self._tracker_words
        m = self.m
        reading = None if m.phase is Phase.RUNNING else m.backend.tracker()
        if reading is None:
            self._tracker_words = [0] * R.TRACKER_WORDS
            return self._tracker_words
        q = np.asarray(reading.quaternion_wxyz, dtype=float)
        q = q / np.linalg.norm(q) * (1.0 if q[0] >= 0 else -1.0)  # one sign: w >= 0
        self.tracker_seq = (self.tracker_seq + 1) & 0xFFFF
        self._tracker_words = codec.encode_tracker(
            codec.TrackerWords(
                valid=True,
                sequence=self.tracker_seq,
                position_um=np.rint(np.asarray(reading.position_m) / R.TRACKER_POSITION_LSB_M),
                quaternion_counts=np.rint(q / R.TRACKER_QUATERNION_LSB),
                cycle=m.cycle_counter,
            )
        )
        return self._tracker_words
