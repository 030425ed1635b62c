"""Command-line values that are not plain scalars, parsed once for every stage."""

from __future__ import annotations

import numpy as np

from rxcomm.errors import InputError


def parse_numbers(text: str, count: int, field: str, unit: str = "") -> np.ndarray:
    """`count` finite comma-separated numbers, else InputError naming the option `field`.

    `unit` (e.g. "rad") only words the message; no conversion happens here."""
    what = f"{count} finite comma-separated numbers" + (f" ({unit})" if unit else "")
    try:
        values = np.array([float(p.strip()) for p in text.split(",")])
    except ValueError as e:
        raise InputError(f"expected {what}, got {text!r}", field=field) from e
    if values.shape != (count,) or not np.all(np.isfinite(values)):
        raise InputError(f"expected {what}, got {text!r}", field=field)
    return values
