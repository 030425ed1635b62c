"""Options of identification (`rxcomm identify`), read by every step of `rxcomm.identification.fit`;
the model lives with the artefact that records it (`rxcomm.schemas.dynamics`)."""

from __future__ import annotations

from rxcomm.schemas.dynamics import IdentifySettings

__all__ = ["IdentifySettings"]
