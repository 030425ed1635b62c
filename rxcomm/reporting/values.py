"""How the report writes a value: "not measured" for None, strings as they are, numbers
scaled to the report's units; a value ± 1σ.
"""

from __future__ import annotations

from rxcomm.reporting.document import (
    NOT_MEASURED,
)


def fmt(x: object, scale: float = 1.0, digits: int = 3, unit: str = "") -> str:
    if x is None:
        return NOT_MEASURED
    if isinstance(x, str):  # e.g. "not applicable (virtual time)": said as it is, never as a number
        return x
    if isinstance(x, list | tuple):
        return "[" + ", ".join(fmt(v, scale, digits) for v in x) + "]" + (f" {unit}" if unit else "")
    return f"{float(x) * scale:.{digits}g}" + (f" {unit}" if unit else "")


def plus_minus(value: float, std: float | None, scale: float, digits: int = 4) -> str:
    if std is None:
        return f"{value * scale:.{digits}g} (fixed)"
    return f"{value * scale:.{digits}g} ± {std * scale:.2g}"
