"""The base of every nested contract model and of the settings models: unknown keys are errors (a typo
must not be ignored) and values are frozen (an artefact read is a fact, not a scratchpad; settings
are dumped into the envelope as they were used)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
