"""The base of every nested contract model: unknown keys are errors (a typo must not be ignored) and
values are frozen (an artefact read is a fact, not a scratchpad)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
