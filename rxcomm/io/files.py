"""File primitives: output checks before any work, atomic (write-then-rename) writes.

A stage never leaves a half-written output (architecture §3): everything is written to ``NAME.part`` in the
same directory (so the rename stays on one file system) and renamed over ``NAME`` only when complete.
Before it reads heavy input or moves anything, a stage calls :func:`check_outputs`, so an output that
would destroy an input, or that cannot be written, is refused in the first second and not after the
work (issue 14).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path

from rxcomm.errors import InputError

PART_SUFFIX = ".part"


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


def check_outputs(
    outputs: Mapping[str, str | Path | None], inputs: Mapping[str, str | Path | None] | None = None
) -> dict[str, Path]:
    """Check every output before any work; InputError (exit 2) names the output and the reason.

    ``outputs`` and ``inputs`` map a name the user knows (the option, e.g. ``"output"``,
    ``"urdf-out"``, ``"measurements"``) to a path (None: not given). A ``NAME.mcap`` stands for
    itself and its summary ``NAME.yaml``. Refused: an output that is also an input (symlinks and hard
    links too) or that an output beside it would overwrite (the summary ``.yaml`` of an ``.mcap``);
    two outputs on one file; a directory; a path under a file; a place this process cannot write.
    Returns the outputs as paths, by name.
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
            e.filename = str(tmp)  # a full disk at write or fsync names no file by itself
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, encoding: str = "utf-8") -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8, newlines as given)."""
    return atomic_write_bytes(path, text.encode(encoding))
