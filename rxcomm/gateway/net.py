"""Address policy shared by the gateway client and the simulated cell's server."""

from __future__ import annotations

import ipaddress
import logging

from rxcomm.errors import InputError


def is_loopback(host: str) -> bool:
    """True for 'localhost' and loopback IP literals; host names are not resolved (no DNS surprises)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def parse_gateway_address(text: str, allow_remote: bool) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 as ``[::1]:1502``); a non-loopback host needs ``allow_remote``."""
    host, sep, port_s = text.strip().rpartition(":")
    host = host.strip("[]")
    try:
        port = int(port_s)
    except ValueError:
        port = -1
    if not sep or not host or not 0 < port < 65536:
        raise InputError(f"expected HOST:PORT, got {text!r}", field="gateway")
    if not is_loopback(host) and not allow_remote:
        raise InputError(
            f"{host} is not a loopback address: a run on a real cell needs --allow-remote", field="gateway"
        )
    return host, port


def quiet_pymodbus() -> None:
    """pymodbus logs its own view of every failure (connection refused, a frame it cannot parse) to
    stderr through logging's last-resort handler, ahead of rxcomm's one-line message. rxcomm reports
    those failures itself: give pymodbus' logger a null handler (a configured root logger still
    receives its records)."""
    log = logging.getLogger("pymodbus")
    if not any(isinstance(h, logging.NullHandler) for h in log.handlers):
        log.addHandler(logging.NullHandler())
