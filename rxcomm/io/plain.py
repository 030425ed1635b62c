"""Conversion of numpy (and path) values to plain JSON/YAML-able Python objects."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import PurePath
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
