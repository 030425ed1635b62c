"""One root exception; a subclass per failure class, each mapped to a CLI exit code.

Exit codes (architecture §7): 0 ok, 2 bad input, 3 infeasible / not converged, 4 gateway or
communication fault, 5 safety stop.
"""

from __future__ import annotations

from pathlib import Path


class RxcommError(Exception):
    """Root of every error rxcomm raises on purpose."""

    exit_code: int = 1


class LocatedError(RxcommError):
    """An error about something a user wrote: the message names the file and the field, then why."""

    def __init__(self, reason: str, *, file: str | Path | None = None, field: str | None = None):
        self.file = str(file) if file is not None else None
        self.field = field
        self.reason = reason
        where = ": ".join(p for p in (self.file, self.field) if p)
        super().__init__(f"{where}: {reason}" if where else reason)


class InputError(LocatedError):
    """Bad input: names the file, the field and the reason."""

    exit_code = 2


class InfeasibleError(LocatedError):
    """A problem with no solution under the given limits, or a solver that did not converge.

    ``file``/``field`` name the limit that makes it so when it is one (e.g. drives.yaml's peak torque).
    """

    exit_code = 3


class GatewayError(RxcommError):
    """Communication with the drive gateway failed (connection, protocol, timeout)."""

    exit_code = 4


class SafetyStop(RxcommError):
    """Motion was stopped for safety (fault, following error, watchdog, e-stop, user abort)."""

    exit_code = 5


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C where a stage installs the handler (`run`): the same quick stop,
    disabled drives, kept log and exit 5, with "terminated (SIGTERM)" in the message."""
