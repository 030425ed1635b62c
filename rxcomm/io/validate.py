"""Validation of loaded data against pydantic models, with failures as InputError(file, field)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from rxcomm.errors import InputError

M = TypeVar("M", bound=BaseModel)


def dotted(loc: tuple[int | str, ...], prefix: str = "") -> str:
    """pydantic ``loc`` ``('joints', 2, 'offset_rad')`` -> ``'joints.2.offset_rad'``."""
    return ".".join(str(p) for p in (prefix, *loc) if p != "")


def _reason(err: dict[str, Any]) -> str:
    if err["type"] == "extra_forbidden":
        return "unknown key"
    if err["type"] == "missing":
        return "required key missing"
    # field_validator messages arrive as "Value error, <ours>"; keep ours.
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "value_error":
        return msg
    return f"{msg} (got {err['input']!r})"[:300]


def validate_model(cls: type[M], data: Any, *, file: str | Path | None, prefix: str = "") -> M:
    """``cls.model_validate(data)``; a ValidationError becomes InputError naming file and the first
    failing field (dotted, after ``prefix``), with the count of further errors."""
    try:
        return cls.model_validate(data)
    except ValidationError as e:
        errs = e.errors(include_url=False)
        first = errs[0]
        more = f" (and {len(errs) - 1} more error(s))" if len(errs) > 1 else ""
        raise InputError(_reason(first) + more, file=file, field=dotted(first["loc"], prefix) or None) from e


def check_kind(data: Any, cls: type, *, file: str | Path | None, prefix: str = "") -> None:
    """Refuse data whose ``kind``/``schema_version`` differ from ``cls.KIND``/``cls.SCHEMA_VERSION``
    before validating anything else, so the message is about the kind and not a cascade of fields."""
    if not isinstance(data, dict):
        raise InputError(f"expected a mapping, got {type(data).__name__}", file=file, field=prefix or None)
    kind, version = data.get("kind"), data.get("schema_version")
    if kind != cls.KIND:
        reason = "missing" if kind is None else f"unknown kind {kind!r}"
        raise InputError(f"{reason}; expected {cls.KIND!r}", file=file, field=dotted(("kind",), prefix))
    if version != cls.SCHEMA_VERSION:
        reason = "missing" if version is None else f"unsupported schema_version {version!r}"
        raise InputError(
            f"{reason}; this rxcomm reads {cls.KIND} version {cls.SCHEMA_VERSION}",
            file=file,
            field=dotted(("schema_version",), prefix),
        )


def settings_from_options(cls: type[M], values: dict[str, Any], options: dict[str, str] | None = None) -> M:
    """A stage's settings model from its command-line values; a ValidationError becomes InputError naming
    the option (``options`` maps a settings field to its option name; default: the field itself)."""
    try:
        return cls(**values)
    except ValidationError as e:
        err = e.errors()[0]
        loc = dotted(err["loc"]) or "options"
        field = (options or {}).get(str(err["loc"][0]) if err["loc"] else loc, loc)
        raise InputError(err["msg"].removeprefix("Value error, "), field=field) from e
