"""The summary YAML written beside a planned trajectory MCAP (``cp.mcap`` -> ``cp.yaml``)."""

from __future__ import annotations

from pydantic import Field

from rxcomm.schemas.envelope import McapSummary


class TrajectorySummary(McapSummary):
    """Envelope + summary of a trajectory MCAP (cp, ptp), plus where its samples are.

    The MCAP carries the same envelope as its ``rxcomm/envelope`` metadata record.
    """

    KIND = "rxcomm/Trajectory"
    SCHEMA_VERSION = 1
    REQUIRED_SUMMARY_KEYS = (
        "duration_s",
        "solve_seconds",
        "max_limit_ratio",
        "active_fraction",
        "q_start",
        "q_goal",
    )

    topic: str = Field(description="MCAP topic of the samples")
    n_samples: int = Field(ge=1)
    fields: list[str] = Field(description="message fields: q, qd, qdd, tau_ff and any extras")
