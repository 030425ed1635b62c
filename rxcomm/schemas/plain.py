"""How values enter an artefact: numpy (and path) values as plain JSON/YAML-able Python, inputs as sha256."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path, PurePath
from typing import Any

import numpy as np


def to_plain(obj: Any) -> Any:
    """Recursively turn numpy scalars/arrays, tuples and paths into plain Python values.

    Mappings keep their key order; arrays become (nested) lists. Anything else is returned as is,
    so pydantic models and datetimes pass through untouched.
    """
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Mapping):
        return {to_plain(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_plain(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    return obj


def sha256_file(path: str | Path, chunk_bytes: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes (the envelope's record of an input)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk_bytes):
            h.update(block)
    return h.hexdigest()
