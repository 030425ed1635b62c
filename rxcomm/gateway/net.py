"""Address policy shared by the gateway client and the simulated cell's server."""

from __future__ import annotations

import ipaddress
import logging


def is_loopback(host: str) -> bool:
    """True for 'localhost' and loopback IP literals; host names are not resolved (no DNS surprises)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def quiet_pymodbus() -> None:
    """pymodbus logs its own view of every failure (connection refused, a frame it cannot parse) to
    stderr through logging's last-resort handler, ahead of rxcomm's one-line message. rxcomm reports
    those failures itself: give pymodbus' logger a null handler (a configured root logger still
    receives its records)."""
    log = logging.getLogger("pymodbus")
    if not any(isinstance(h, logging.NullHandler) for h in log.handlers):
        log.addHandler(logging.NullHandler())
