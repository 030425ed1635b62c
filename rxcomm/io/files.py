"""File primitives: atomic (write-then-rename) writes.

A stage never leaves a half-written output (architecture §3): everything is written to ``NAME.part`` in the
same directory (so the rename stays on one file system) and renamed over ``NAME`` only when complete.
"""

from __future__ import annotations

import os
from pathlib import Path

PART_SUFFIX = ".part"


def part_path(path: str | Path, suffix: str = PART_SUFFIX) -> Path:
    """The temporary sibling ``NAME.part`` an output is written to before the rename."""
    path = Path(path)
    return path.with_name(path.name + suffix)


def atomic_write_bytes(path: str | Path, data: bytes, *, part_suffix: str = PART_SUFFIX) -> Path:
    """Write ``data`` to ``path`` via ``path + part_suffix`` and ``os.replace``.

    On any failure (including KeyboardInterrupt) the partial file is removed and the error re-raised,
    so ``path`` is either the old file or the complete new one.
    """
    path = Path(path)
    tmp = part_path(path, part_suffix)
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, encoding: str = "utf-8") -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8, newlines as given)."""
    return atomic_write_bytes(path, text.encode(encoding))
