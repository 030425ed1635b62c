"""File primitives: output checks before any work, atomic (write-then-rename) writes.

A stage never leaves a half-written output (architecture §3): everything is written to ``NAME.part`` in the
same directory (so the rename stays on one file system) and renamed over ``NAME`` only when complete.
Before it reads heavy input or moves anything, a stage calls :func:`check_outputs`, so an output that
would destroy an input, or that cannot be written, is refused in the first second and not after the
work (issue 14).

One output policy for every stage (issue 27), applied by :func:`check_outputs` once the checks pass:
missing directories are created; each output is locked for this process (``.NAME.lock`` beside it,
``fcntl.flock``), so a second writer of the same output stops at once naming the lock instead of
sharing its ``.part``; an existing ``NAME.part`` (a killed or stopped writer's, e.g. a recoverable run
log) is moved aside to ``NAME.part.N`` (the next free N) and named on stderr, never replaced.
"""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import os
import sys
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

from rxcomm.errors import InputError

PART_SUFFIX = ".part"
LOCK_SUFFIX = ".lock"


def _stderr_note(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


# Where a moved-aside ``.part`` (or an artefact accepted with a warning) is announced: a plain stderr
# line, the console's own format without a terminal (tests may replace it).
notice: Callable[[str], None] = _stderr_note
_held_locks: dict[Path, tuple[int, Path]] = {}  # output (resolved) -> (fd, lock file) held by this process


def part_path(path: str | Path, suffix: str = PART_SUFFIX) -> Path:
    """The temporary sibling ``NAME.part`` an output is written to before the rename."""
    path = Path(path)
    return path.with_name(path.name + suffix)


def mcap_summary_path(mcap_path: str | Path) -> Path:
    """``cp.mcap`` -> ``cp.yaml``: the summary YAML every trajectory or log MCAP has beside it."""
    return Path(mcap_path).with_suffix(".yaml")


def trajectory_output(output: str | Path) -> Path:
    """A trajectory stage's ``-o``: NAME.mcap, its summary NAME.yaml written beside it."""
    if Path(output).suffix != ".mcap":
        raise InputError("the output must be NAME.mcap (NAME.yaml is written beside it)", field="output")
    return Path(output)


def _same_file(a: Path, b: Path) -> bool:
    """Same resolved path, or (both existing) the same inode: symlinks and hard links included."""
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except (OSError, RuntimeError):  # a symlink loop: not the same as any real file
        return False


def _with_siblings(files: Mapping[str, str | Path | None]) -> list[tuple[str, Path, Path]]:
    """(name, path, the file as given) for each file, each ``NAME.mcap`` followed by its summary
    ``NAME.yaml`` (written or read with it)."""
    out: list[tuple[str, Path, Path]] = []
    for name, p in files.items():
        if p is None:
            continue
        p = Path(p)
        out.append((name, p, p))
        if p.suffix == ".mcap":
            out.append((name, mcap_summary_path(p), p))
    return out


def _check_writable_place(path: Path, field: str, *, directory: bool) -> None:
    """Refuse ``path`` if it is (or would need) a directory where a file is, or sits where this
    process cannot create files. ``directory``: ``path`` itself is a directory to write into."""
    if path.exists() and not directory and path.is_dir():
        raise InputError("is a directory; name a file to write", file=path, field=field)
    if path.exists() and directory and not path.is_dir():
        raise InputError("is a file; name a directory to write into", file=path, field=field)
    start = path if directory else path.parent
    ancestor = start
    while not ancestor.exists():
        if ancestor.is_symlink():  # a dangling link: mkdir would fail on it
            raise InputError(f"{ancestor} is a dangling symbolic link", file=path, field=field)
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise InputError(
            f"cannot write under {ancestor}: it is a file, not a directory", file=path, field=field
        )
    # os.access is not enough (root, read-only mounts, ACLs, sysfs): create and remove a probe file
    try:
        fd, probe = tempfile.mkstemp(prefix=".rxcomm-probe-", suffix=PART_SUFFIX, dir=ancestor)
    except OSError as e:
        raise InputError(f"cannot write in {ancestor}: {e.strerror or e}", file=path, field=field) from e
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(probe)


def lock_path(path: str | Path) -> Path:
    """``dir/NAME`` -> ``dir/.NAME.lock``: the lock a writer of ``NAME`` holds."""
    path = Path(path)
    return path.with_name(f".{path.name}{LOCK_SUFFIX}")


def lock_output(path: str | Path, field: str = "output") -> Path:
    """Hold ``.NAME.lock`` (``fcntl.flock``, not blocking) until :func:`release_outputs` or the process
    ends; InputError (exit 2) naming the lock when another process holds it. Re-entrant in one process.
    Returns the lock file."""
    path = Path(path)
    key = path.resolve()
    if key in _held_locks:
        return _held_locks[key][1]
    lock = lock_path(path)
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise InputError(
                f"another process is writing this output (it holds the lock {lock}); wait for it or "
                "choose another output",
                file=path,
                field=field,
            ) from None
        # the holder before us may have removed the lock file after we opened it: lock the file
        # that is there now, or two writers would each hold a different one
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    os.write(fd, f"{os.getpid()}\n".encode())
    _held_locks[key] = (fd, lock)
    return lock


def release_outputs() -> None:
    """Release (and remove) every output lock this process holds."""
    for fd, lock in _held_locks.values():
        with contextlib.suppress(OSError):
            lock.unlink()
        with contextlib.suppress(OSError):
            os.close(fd)
    _held_locks.clear()


atexit.register(release_outputs)


def set_aside_part(path: str | Path) -> Path | None:
    """Move an existing ``NAME.part`` to ``NAME.part.N`` (the next free N) and name it on the console;
    returns where it went (None: there was none). Call it holding the output's lock."""
    part = part_path(path)
    if not part.exists() and not part.is_symlink():
        return None
    n = 1
    while (aside := part.with_name(f"{part.name}.{n}")).exists() or aside.is_symlink():
        n += 1
    os.rename(part, aside)
    notice(
        f"note: {part} of an earlier run kept as {aside} "
        f"(a run log's is recovered by `rxcomm recover-log {aside}`)"
    )
    return aside


def check_outputs(
    outputs: Mapping[str, str | Path | None], inputs: Mapping[str, str | Path | None] | None = None
) -> dict[str, Path]:
    """Check every output before any work; InputError (exit 2) names the output and the reason.

    ``outputs`` and ``inputs`` map a name the user knows (the option, e.g. ``"output"``,
    ``"urdf-out"``, ``"measurements"``) to a path (None: not given). A ``NAME.mcap`` stands for
    itself and its summary ``NAME.yaml``. Refused: an output that is also an input (symlinks and hard
    links too) or that an output beside it would overwrite (the summary ``.yaml`` of an ``.mcap``);
    two outputs on one file; a directory; a path under a file; a place this process cannot write.
    List every file the stage writes beside its output too (the ``.csv`` of ``--mdh-out``, a ``.png``).
    Then the policy of the module docstring: directories created, each output locked, an old
    ``NAME.part`` moved aside. Returns the outputs as paths, by name.
    """
    outs = _with_siblings(outputs)
    ins = _with_siblings(inputs or {})
    for k, (name, out, given) in enumerate(outs):
        what = str(out) if out == given else f"its summary {out}"
        for in_name, inp, in_given in ins:
            if _same_file(out, inp):
                of = "" if inp == in_given else f"the summary of {in_given}, "
                raise InputError(
                    f"{what} is also the input {in_name} ({of}{inp}): writing it would destroy the input; "
                    "choose another output name",
                    file=given,
                    field=name,
                )
        for other_name, other, _ in outs[:k]:
            if _same_file(out, other):
                raise InputError(f"{what} is also the output {other_name}", file=given, field=name)
        _check_writable_place(out, name, directory=False)
    for name, out, _ in outs:
        out.parent.mkdir(parents=True, exist_ok=True)
        lock_output(out, name)
    for _, out, _ in outs:
        set_aside_part(out)
    return {name: out for name, out, given in outs if out == given}


def check_output_dir(
    path: str | Path, field: str, inputs: Mapping[str, str | Path | None] | None = None
) -> Path:
    """:func:`check_outputs` for a directory a stage writes files into (it may not exist yet)."""
    path = Path(path)
    for in_name, inp, _ in _with_siblings(inputs or {}):
        if _same_file(path, inp):
            raise InputError(f"is also the input {in_name}", file=path, field=field)
    _check_writable_place(path, field, directory=True)
    path.mkdir(parents=True, exist_ok=True)
    return path


def atomic_write_bytes(path: str | Path, data: bytes, *, part_suffix: str = PART_SUFFIX) -> Path:
    """Write ``data`` to ``path`` via ``path + part_suffix`` and ``os.replace``.

    On any failure (including KeyboardInterrupt) the partial file is removed and the error re-raised,
    so ``path`` is either the old file or the complete new one. A failing cleanup never replaces the
    first error (a path under a file fails the same way twice).
    """
    path = Path(path)
    tmp = part_path(path, part_suffix)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        if isinstance(e, OSError) and e.errno is not None and e.filename is None:
            # a full disk at write or fsync names no file by itself: name the .part, or for a file that
            # is itself a .part (a campaign's poses so far) that file, not a NAME.part.part
            e.filename = str(path if path.name.endswith(PART_SUFFIX) else tmp)
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, encoding: str = "utf-8") -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8, newlines as given)."""
    return atomic_write_bytes(path, text.encode(encoding))
