"""One root exception; a subclass per failure class, each mapped to a CLI exit code.

Exit codes (architecture §7): 0 ok, 2 bad input, 3 infeasible / not converged, 4 gateway or
communication fault, 5 safety stop.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
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


# ---- how a solver says how it ended ----------------------------------------------------------------


class SolveStatus(StrEnum):
    """How a numerical solve ended: the one convention of the solvers' results (their ``outcome``)."""

    SOLVED = "solved"
    INFEASIBLE = "infeasible"  # no solution exists under the limits (uncontrollable path, infeasible NLP)
    NOT_CONVERGED = "not_converged"  # the budget (iterations, wall time) ran out, or the solver stalled


# IPOPT's return_status values that mean the problem itself has no solution.
_IPOPT_INFEASIBLE = {"Infeasible_Problem_Detected", "Converged_To_Local_Infeasibility"}


@dataclass(frozen=True)
class SolveOutcome:
    """A solver's status and, unless solved, a message saying why (for the error it becomes, exit 3)."""

    status: SolveStatus
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.status is SolveStatus.SOLVED

    def raise_if_failed(self, what: str) -> None:
        """Raise ``InfeasibleError("WHAT: MESSAGE")`` unless solved."""
        if not self.ok:
            raise InfeasibleError(f"{what}: {self.message or self.status.value}")

    @classmethod
    def from_ipopt(cls, return_status: str, success: bool, iterations: int) -> SolveOutcome:
        """From IPOPT's ``return_status`` and ``success`` (CasADi's solver stats)."""
        if success:
            return cls(SolveStatus.SOLVED)
        status = SolveStatus.INFEASIBLE if return_status in _IPOPT_INFEASIBLE else SolveStatus.NOT_CONVERGED
        return cls(status, f"IPOPT {return_status} after {iterations} iterations")


class GatewayError(RxcommError):
    """Communication with the drive gateway failed (connection, protocol, timeout)."""

    exit_code = 4


class SafetyStop(RxcommError):
    """Motion was stopped for safety (fault, following error, watchdog, e-stop, user abort)."""

    exit_code = 5


class DriveTrip(SafetyStop):
    """A drive faulted on the motion itself (following error 0x8611, a torque or position fault): what
    the plan did to this robot and its loops, not an operator's or the link's stop."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C where a stage installs the handler (`run`): the same quick stop,
    disabled drives, kept log and exit 5, with "terminated (SIGTERM)" in the message."""
