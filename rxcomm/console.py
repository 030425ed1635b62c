"""The one place stages report through: human summaries and progress on stderr/stdout, error exits.

Library code never prints; stages call these helpers.
"""

from __future__ import annotations

import errno
import functools
import sys
from collections.abc import Callable
from typing import TypeVar

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from rxcomm.errors import GatewayError, InputError, RxcommError

# soft_wrap: never hard-wrap at 80 columns when output goes to a file or a pipe (make, CI logs).
out = Console(highlight=False, soft_wrap=True)
err = Console(stderr=True, highlight=False, soft_wrap=True)

T = TypeVar("T")


def fail(e: RxcommError) -> typer.Exit:
    """Print a one-line reason and return the matching exit (caller raises it)."""
    err.print(f"[bold red]error[/]: {escape(str(e))}", soft_wrap=True)
    return typer.Exit(code=e.exit_code)


def os_error(e: OSError) -> RxcommError:
    """An OS error (full disk, permissions, a vanished directory) as bad input (exit 2), a lost
    connection as a communication fault (exit 4): one line naming the file and the reason, the
    OSError kept as the cause."""
    reason = e.strerror or str(e) or type(e).__name__
    if e.errno is not None and e.errno in errno.errorcode:
        reason += f" ({errno.errorcode[e.errno]})"
    files = [f for f in (e.filename, e.filename2) if f is not None]
    if len(files) == 2:
        reason += f" (renaming to {files[1]})"
    if isinstance(e, ConnectionError | TimeoutError):
        err: RxcommError = GatewayError(f"connection: {reason}")
    else:
        err = InputError(reason, file=files[0] if files else None)
    err.__cause__ = e
    return err


def stage_command(fn: Callable[..., T]) -> Callable[..., T]:
    """Wrap a typer command so RxcommError (and OSError, as bad input) becomes a one-line message
    and its exit code."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except RxcommError as e:
            raise fail(e) from e
        except OSError as e:
            raise fail(os_error(e)) from e
        except KeyboardInterrupt:
            err.print("interrupted")
            raise typer.Exit(code=5) from None

    return wrapper


def checked(fn: Callable[..., T], *args) -> T:
    """`fn(*args)` in a command function (e.g. an option pair converted to radians), with an
    RxcommError turned into its one-line message and exit code, as `stage_command` does."""
    try:
        return fn(*args)
    except RxcommError as e:
        raise fail(e) from e


def progress() -> Progress:
    """A progress bar on stderr (silent when stderr is not a terminal, so logs stay clean)."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=False,
        disable=not sys.stderr.isatty(),
    )


def summary_table(title: str, rows: dict[str, object]) -> None:
    """Print a stage's summary mapping as aligned `name  value` lines."""
    out.print(f"[bold]{title}[/]")
    width = max((len(k) for k in rows), default=0)
    for k, v in rows.items():
        out.print(f"  {k:<{width}}  {_fmt(v)}")


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)
