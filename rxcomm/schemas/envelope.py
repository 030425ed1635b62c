"""The artefact envelope every rxcomm artefact carries (architecture §3).

Subclasses are the artefacts of the stages. A kind is declared in its class line: ``Artefact`` is
parametrised by the kind's settings and summary models (`Strict`: an unknown or renamed key is an
error naming it; units in the field names; an optional field is None when not measured, and an older
file without it still reads), and the class keywords ``kind`` and ``schema_version`` set the class
variables ``KIND`` (``"rxcomm/Calibration"``) and ``SCHEMA_VERSION``. The kind's data fields follow
the envelope fields::

    class Calibration(Artefact[CalibrateSettings, CalibrationSummary], kind="rxcomm/Calibration",
                      schema_version=2):
        robot: str
        params_m: list[float]

    cal = Calibration(**Calibration.envelope({"robot": urdf_path}, settings, summary), params_m=[...])

A kind that leaves ``summary`` or ``settings`` a dict (not parametrised) is refused when its class is
defined. The bare ``Artefact`` (no ``KIND``) validates the envelope fields of any kind; the MCAP
reader uses it. The summary YAML beside an MCAP (a trajectory, a run log) derives from
``McapSummary``, which adds the MCAP's file name and hash after the envelope. A base of kinds that is
no kind itself says ``__abstract__ = True``; a kind that overrides ``settings`` or ``summary`` (to
describe it) keeps the same model.
"""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any, ClassVar, Generic, get_args

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    ValidationInfo,
    field_validator,
    model_validator,
)
from typing_extensions import TypeVar

import rxcomm
from rxcomm.code_identity import code_identity
from rxcomm.schemas.plain import sha256_file, to_plain

Sha256Hex = Annotated[str, StringConstraints(pattern=r"^[0-9a-f]{64}$")]
SummaryValue = float | int | str | bool | list[float] | list[int] | list[float | None] | None
ENVELOPE_FIELDS = (
    "kind",
    "schema_version",
    "created",
    "rxcomm_version",
    "code_identity",
    "inputs",
    "settings",
    "summary",
)
# A kind's settings and summary models; the bare envelope (any kind) reads them as mappings.
SettingsT = TypeVar("SettingsT", default=dict[str, Any])
SummaryT = TypeVar("SummaryT", default=dict[str, SummaryValue])


def _schema_extra(schema: dict[str, Any], cls: type) -> None:
    """Pin ``kind``/``schema_version`` in the generated JSON Schema."""
    props = schema.get("properties", {})
    if kind := getattr(cls, "KIND", None):
        props["kind"]["const"] = kind
    if (version := getattr(cls, "SCHEMA_VERSION", None)) is not None:
        props["schema_version"]["const"] = version


def _is_model(annotation: Any) -> bool:
    """A pydantic model, or a union of them (a kind written by several stages)."""
    if isinstance(annotation, type):
        return issubclass(annotation, BaseModel)
    args = get_args(annotation)
    return bool(args) and all(_is_model(a) for a in args)


class Artefact(BaseModel, Generic[SettingsT, SummaryT]):
    """Envelope fields shared by every artefact; subclasses add their data after them."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=_schema_extra)

    KIND: ClassVar[str]
    SCHEMA_VERSION: ClassVar[int]

    kind: str
    schema_version: int
    created: datetime
    rxcomm_version: str
    # None: an artefact written before code identities (it still reads).
    code_identity: str | None = Field(
        None,
        description="the code that wrote it: version, git describe of its checkout, sha256 of its sources "
        "(rxcomm/code_identity.py)",
    )
    inputs: dict[str, Sha256Hex]
    settings: SettingsT
    summary: SummaryT

    def __init_subclass__(cls, kind: str | None = None, schema_version: int | None = None, **kwargs: Any):
        # The class keywords of a kind's class line (pydantic passes them on here and below).
        super().__init_subclass__(**kwargs)
        if kind is not None:
            cls.KIND = kind
        if schema_version is not None:
            cls.SCHEMA_VERSION = schema_version

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        kwargs.pop("kind", None)
        kwargs.pop("schema_version", None)
        super().__pydantic_init_subclass__(**kwargs)
        # A base of kinds, or a parametrisation `Artefact[S, U]` on its way to one.
        if cls.__dict__.get("__abstract__") or cls.__pydantic_generic_metadata__["origin"] is not None:
            return
        if not isinstance(getattr(cls, "KIND", None), str) or not isinstance(
            getattr(cls, "SCHEMA_VERSION", None), int
        ):
            raise TypeError(
                f"{cls.__name__} must set kind= (a str) and schema_version= (an int) in its class line"
            )
        for name in ("summary", "settings"):
            if not _is_model(cls.model_fields[name].annotation):
                raise TypeError(
                    f"{cls.__name__}.{name} must be a pydantic model (units in its field names): "
                    "parametrise Artefact[SettingsModel, SummaryModel]"
                )

    @model_validator(mode="before")
    @classmethod
    def _numpy_to_plain(cls, data: Any) -> Any:
        # Lets stages pass numpy arrays/scalars straight in; the stored model holds plain values.
        return to_plain(data) if isinstance(data, dict) else data

    @field_validator("kind", "schema_version")
    @classmethod
    def _pinned(cls, v: str | int, info: ValidationInfo) -> str | int:
        """``kind`` and ``schema_version`` equal the class's ``KIND`` and ``SCHEMA_VERSION`` (any on the
        bare envelope)."""
        kind = info.field_name == "kind"
        expected = getattr(cls, "KIND" if kind else "SCHEMA_VERSION", None)
        if expected is not None and v != expected:
            raise ValueError(
                f"unknown kind {v!r}; expected {expected!r}"
                if kind
                else f"unsupported schema_version {v}; this rxcomm reads version {expected}"
            )
        return v

    @field_validator("created")
    @classmethod
    def _utc(cls, v: datetime) -> datetime:
        if v.tzinfo is None:
            raise ValueError("created must carry a time zone (UTC, e.g. 2025-01-31T12:00:00Z)")
        return v.astimezone(UTC)

    @classmethod
    def envelope(
        cls,
        inputs: dict[str, str | Path],
        settings: BaseModel | dict[str, Any] | None = None,
        summary: BaseModel | dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """Envelope fields for a new artefact of this class: hashes ``inputs`` (name -> file path),
        dumps ``settings`` as JSON-able, stamps ``created`` (UTC, now), ``rxcomm.__version__`` and the
        code identity (``rxcomm.code_identity``)."""
        if isinstance(settings, BaseModel):
            settings_d = settings.model_dump(mode="json")
        else:
            settings_d = to_plain(dict(settings or {}))
        return {
            "kind": cls.KIND,
            "schema_version": cls.SCHEMA_VERSION,
            "created": datetime.now(UTC).replace(microsecond=0),
            "rxcomm_version": rxcomm.__version__,
            "code_identity": code_identity(),
            "inputs": {name: sha256_file(p) for name, p in inputs.items()},
            "settings": settings_d,
            "summary": summary.model_dump(mode="json")
            if isinstance(summary, BaseModel)
            else to_plain(dict(summary or {})),
        }

    def envelope_dict(self) -> dict[str, Any]:
        """The envelope fields of this artefact as JSON-able values (for an MCAP metadata record)."""
        return self.model_dump(mode="json", include=set(ENVELOPE_FIELDS))


class McapSummary(Artefact[SettingsT, SummaryT]):
    """The summary YAML beside an MCAP (``NAME.mcap`` -> ``NAME.yaml``): envelope, the MCAP's file name
    and hash, then the kind's fields. The MCAP carries the same envelope as its ``rxcomm/envelope``
    metadata record."""

    __abstract__ = True

    mcap_file: str = Field(description="file name of the MCAP beside this YAML")
    mcap_sha256: Sha256Hex = Field(description="sha256 of that MCAP, to tie the summary to its samples")
