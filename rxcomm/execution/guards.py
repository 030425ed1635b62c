"""What a run checks and handles around the motion (issue 27): its option ranges and output kind
before anything is read, a model other than the plan's, and SIGTERM handled as Ctrl-C is (quick stop,
drives disabled, log kept, exit 5)."""

from __future__ import annotations

import contextlib
import math
import signal
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

from rxcomm.errors import InputError, Terminated
from rxcomm.gateway.registers import INTERPOLATION_RATIO_MAX


def check_run_options(interpolation_ratio: int | None, speed: float) -> None:
    """Exit 2 before anything is read: R in 1..64, the speed fraction in (0, 1]."""
    r_max = INTERPOLATION_RATIO_MAX
    if interpolation_ratio is not None and not 1 <= interpolation_ratio <= r_max:
        raise InputError(
            f"{interpolation_ratio} drive cycles per setpoint: must be 1 to {r_max}",
            field="interpolation-ratio",
        )
    if not (math.isfinite(speed) and 0.0 < speed <= 1.0):
        raise InputError(
            f"{speed}: a fraction of the velocity/acceleration limits must be > 0 and <= 1",
            field="speed-fraction",
        )


_terminated = threading.Event()
_deferred = [0]  # > 0 while the gateway is talked to: SIGTERM waits for a clean point


def sigterm_as_interrupt() -> Callable[[], None]:
    """SIGTERM stops a run as Ctrl-C does: quick stop, drives disabled, log kept, exit 5. Outside the
    cell's session it raises ``Terminated`` (a KeyboardInterrupt) at once; inside
    (:func:`deferred_termination`) at the next clean point (:func:`raise_if_terminated`, between two
    gateway transactions), so no request is cut in half and the quick stop still gets through.
    Returns the call that restores the previous handler."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    _terminated.clear()

    def handler(signum: int, frame: object) -> None:
        _terminated.set()
        if not _deferred[0]:
            raise Terminated()

    previous = signal.signal(signal.SIGTERM, handler)
    return lambda: signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def deferred_termination() -> Iterator[None]:
    """Within: a SIGTERM takes effect at the next :func:`raise_if_terminated`."""
    _deferred[0] += 1
    try:
        yield
    finally:
        _deferred[0] -= 1


def raise_if_terminated() -> None:
    """Raise ``Terminated`` once if a SIGTERM came (the stop that follows is not interrupted again)."""
    if _terminated.is_set():
        _terminated.clear()
        raise Terminated()


def check_output_kind(kind: str, output: Path) -> None:
    want = ".mcap" if kind == "trajectory" else ".yaml"
    if output.suffix != want:
        what = (
            "a run log NAME.mcap (NAME.yaml beside it)" if kind == "trajectory" else "measurements NAME.yaml"
        )
        raise InputError(f"a {kind} plan writes {what}", file=output, field="output")


def other_model_warning(plan: Path, dynamics: Path) -> str | None:
    """What to warn (not refuse: run checks every torque of the plan against the limits with its own
    model) when ``--dynamics`` is not the model a trajectory plan was made with (its envelope's hash)."""
    from rxcomm.io.mcap_io import read_mcap_envelope
    from rxcomm.schemas.plain import sha256_file

    if Path(plan).suffix != ".mcap":
        return None
    made = (read_mcap_envelope(plan).get("inputs") or {}).get("dynamics")
    if not isinstance(made, str) or made == sha256_file(dynamics):
        return None
    return (
        f"{plan} was planned with another dynamics model (sha256 {made[:12]}…) than --dynamics "
        f"{dynamics}: the feed-forward and torque checks use {dynamics}; re-plan to match"
    )
