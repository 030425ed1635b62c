"""The one place stages report through: human summaries and progress on stderr/stdout, error exits.

Library code never prints; stages call these helpers.
"""

from __future__ import annotations

import errno
import functools
import sys
import threading
import time
from collections.abc import Callable
from typing import Any, TypeVar

import typer
from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from rxcomm.errors import GatewayError, InputError, RxcommError, Terminated
from rxcomm.io.files import release_outputs

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
        except KeyboardInterrupt as e:
            err.print("terminated (SIGTERM)" if isinstance(e, Terminated) else "interrupted")
            raise typer.Exit(code=5) from None
        finally:
            release_outputs()  # the outputs' locks (rxcomm.io.files.check_outputs), for the next stage

    return wrapper


def checked(fn: Callable[..., T], *args) -> T:
    """`fn(*args)` in a command function (e.g. an option pair converted to radians), with an
    RxcommError turned into its one-line message and exit code, as `stage_command` does."""
    try:
        return fn(*args)
    except RxcommError as e:
        raise fail(e) from e


# Without a terminal (make, CI) a bar cannot redraw: each running task is printed as one plain line
# this often instead, so a log never sits silent for minutes.
PLAIN_PERIOD_S = 5.0


def progress() -> Progress | PlainProgress:
    """A progress bar on stderr; when stderr is not a terminal, plain periodic lines instead."""
    if not sys.stderr.isatty():
        return PlainProgress()
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=False,
    )


def named_progress() -> tuple[Callable[[str, float], None], Callable[[], None]]:
    """A started progress display and (update(what, fraction), stop): a bar per named task."""
    bar = progress()
    bar.start()
    tasks: dict[str, Any] = {}

    def update(what: str, fraction: float) -> None:
        if what not in tasks:
            tasks[what] = bar.add_task(what, total=1000)
        bar.update(tasks[what], completed=int(1000 * fraction))

    return update, bar.stop


class PlainProgress:
    """The part of rich's Progress the stages use, printing `description: 40 % 12 s` (or, without a
    total, `description: 12 s`) for every unfinished task each `period_s`, from a daemon thread so a
    long library call without progress callbacks is still reported. A task that ran longer than one
    period gets a last line when it finishes or the display stops."""

    def __init__(self, period_s: float | None = None, stream=None):
        self.period_s = PLAIN_PERIOD_S if period_s is None else period_s
        self.stream = stream
        self._tasks: dict[int, dict] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def add_task(self, description: str, total: float | None = None, **_) -> int:
        with self._lock:
            task_id = len(self._tasks)
            self._tasks[task_id] = {
                "description": description, "total": total, "completed": 0.0,
                "t0": time.monotonic(), "done": False,
            }  # fmt: skip
        return task_id

    def update(self, task_id: int, *, completed: float | None = None, advance: float | None = None,
               description: str | None = None, **_) -> None:  # fmt: skip
        with self._lock:
            t = self._tasks[task_id]
            if description is not None:
                t["description"] = description
            if completed is not None:
                t["completed"] = completed
            if advance is not None:
                t["completed"] += advance
            finished = t["total"] is not None and t["completed"] >= t["total"] and not t["done"]
        if finished:
            self._finish(task_id)

    def start(self) -> None:
        if self._thread is None:
            self._thread = threading.Thread(target=self._tick, daemon=True, name="rxcomm-progress")
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        for task_id in list(self._tasks):
            self._finish(task_id)

    def __enter__(self) -> PlainProgress:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def line(self, task_id: int) -> str:
        t = self._tasks[task_id]
        elapsed = time.monotonic() - t["t0"]
        share = f" {100 * t['completed'] / t['total']:.0f} %" if t["total"] else ""
        return f"{t['description']}:{share} {elapsed:.0f} s"

    def _emit(self, text: str) -> None:
        print(text, file=self.stream or sys.stderr, flush=True)

    def _finish(self, task_id: int) -> None:
        with self._lock:
            t = self._tasks[task_id]
            if t["done"]:
                return
            t["done"] = True
            long = time.monotonic() - t["t0"] >= self.period_s
            reached = t["total"] is None or t["completed"] >= t["total"]
        if long:  # a task the display stopped short of its total did not finish: say so
            self._emit(self.line(task_id) + (" (done)" if reached else " (stopped)"))

    def _tick(self) -> None:
        while not self._stop.wait(self.period_s):
            with self._lock:
                running = [k for k, t in self._tasks.items() if not t["done"]]
            for task_id in running:
                self._emit(self.line(task_id))


class Phase:
    """A phase without a known fraction (a solve): a spinner with the elapsed time on a terminal,
    plain periodic lines otherwise. `update(text)` renames it (as rich's status does)."""

    def __init__(self, description: str):
        self.bar = progress()
        if isinstance(self.bar, Progress):
            self.bar.columns = (SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn())
        self.task = self.bar.add_task(description, total=None)

    def update(self, description: str) -> None:
        self.bar.update(self.task, description=description)

    def __enter__(self) -> Phase:
        self.bar.start()
        return self

    def __exit__(self, *exc) -> None:
        self.bar.stop()


def phase(description: str) -> Phase:
    """`with console.phase("plan-ptp: solving"):` around a long call that reports no progress."""
    return Phase(description)


def summary_table(title: str, rows: dict[str, object] | BaseModel) -> None:
    """Print a stage's summary (a mapping, or an artefact's summary model: the fields it was given)
    as aligned `name  value` lines."""
    if isinstance(rows, BaseModel):
        rows = rows.model_dump(exclude_unset=True)
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
