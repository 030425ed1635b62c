"""The gateway's logic, without threads or sockets: register writes in, register images out, one
drive cycle at a time. ``server.py`` wraps it in pymodbus and a clock; tests can drive it directly.

``GatewayCore`` is the state machine of ``gateway_machine.py`` (drives, stream phases, stops, the
drive cycle) with map v1 on top: this module routes an address to its section, ``register_writes.py``
applies writes and ``register_images.py`` renders reads (docs/gateway.md).

Not thread-safe: the caller serialises every call (the server holds one lock around each).
"""

from __future__ import annotations

from rxcomm.cell.backend import CellBackend
from rxcomm.cell.gateway_machine import CoreLimits, GatewayMachine
from rxcomm.cell.register_images import RegisterImages
from rxcomm.cell.register_writes import EXC_ADDRESS, EXC_BUSY, EXC_VALUE, WRITERS
from rxcomm.gateway import registers as R

_SECTIONS = R.sections()
_DEFAULT_LIMITS = CoreLimits()


class GatewayCore(GatewayMachine):
    """Register-level behaviour of the gateway and its six CiA 402 drives (docs/gateway.md)."""

    def __init__(self, backend: CellBackend, limits: CoreLimits = _DEFAULT_LIMITS):
        super().__init__(backend, limits)
        self.images = RegisterImages(self)

    def handle_write(
        self, address: int, values: list[int], now_s: float, conn: object | None = None
    ) -> int | None:
        """Apply a write from connection ``conn``; None or a Modbus exception code.

        While a master has claimed the gateway (register 28), writes from any other connection are
        refused with exception 3, except to the simulator's fault injection (the world outside)."""
        end = address + len(values)
        for name, base, count, read_only in _SECTIONS:
            if base <= address and end <= base + count:
                if read_only:
                    return EXC_ADDRESS
                if self.owner_token and conn is not self.owner and name != "sim":
                    return EXC_VALUE
                exc = WRITERS[name](self, address - base, values, conn)
                if exc is None or exc == EXC_BUSY:  # a busy answer proves the master alive
                    self.last_write_s = now_s
                if exc is None:
                    self.advance_phase()
                return exc
        return EXC_ADDRESS

    def handle_read(self, address: int, count: int) -> list[int] | int:
        """Words for [address, address + count), or exception code 2 for undefined addresses."""
        end = address + count
        words: list[int] = []
        pos = address
        for name, base, n, _ in _SECTIONS:
            if base <= pos < base + n:
                image = self.images.section(name, sample=(name == "tracker" and pos == base))
                words += image[pos - base : min(end, base + n) - base]
                pos = min(end, base + n)
                if pos == end:
                    return words
        return EXC_ADDRESS
