"""Options of identification (`rxcomm identify`), read by every step of `rxcomm.identification.fit`."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from rxcomm.schemas.strict import Strict


class IdentifySettings(Strict):
    """Options of `rxcomm identify` (units in the names)."""

    cutoff_hz: Annotated[float, Field(gt=0)] | Literal["auto"] = Field(
        10.0,
        description="low-pass cut-off of positions and torques, Hz; auto: the grid value with the least "
        "cross-validated held-out error (`rxcomm.identification.cross_validation.choose_cutoff`)",
    )
    cutoff_grid_hz: tuple[Annotated[float, Field(gt=0)], ...] = Field(
        (5.0, 10.0, 20.0, 40.0), min_length=2, description="cut-offs tried by cutoff_hz auto, Hz"
    )
    filter_order: int = Field(4, ge=1, le=8, description="Butterworth order (doubled by the zero-phase pass)")
    decimate_hz: float | None = Field(
        None,
        gt=0,
        description="sample rate after filtering and differentiation, Hz; None: 2 × cutoff_hz (rows "
        "uncorrelated)",
    )
    folds: int = Field(
        5,
        ge=0,
        description="blocked cross-validation: the log cut into this many contiguous folds in time, each "
        "predicted by a fit on the others (0: none)",
    )
    min_speed_rad_s: float = Field(
        0.05, ge=0, description="rows of a joint slower than this are rejected (friction sign uncertain)"
    )
    standstill_speed_rad_s: float = Field(
        0.005,
        ge=0,
        description="the prediction takes a joint slower than this as standing (zero velocity: no "
        "Coulomb term), never the sign of the noise in q̇; above the filtered q̇'s noise (≈1e-4 rad/s "
        "for 2e-5 rad encoder noise at 10 Hz), below any motion (a stop passes it in a few ms)",
    )
    method: Literal["wls", "ols"] = Field("wls", description="weighted (per-joint noise) or ordinary LS")
    physical: bool = Field(False, description="write the physically consistent estimate")
    holdout_fraction: float = Field(
        0.2, gt=0, lt=0.9, description="part of the log held out for validation without --validate"
    )
    holdout_blocks: int = Field(
        5,
        ge=1,
        description="without --validate the log is cut into this many blocks and the last holdout_fraction "
        "of each is held out (interleaved: a log that ends at standstill still validates on motion; "
        "1 = the last part of the log)",
    )
    friction: Literal["joint", "motor", "both"] | None = Field(
        None, description="friction model; None: drives.yaml's (`Robot.friction_mode`)"
    )
    min_rows_per_parameter: float = Field(
        10.0, gt=0, description="fewer fit rows per base parameter than this gets a warning and a suggestion"
    )
    max_cond: float = Field(
        1e4, gt=1, description="refuse a log whose unit-column base regressor is worse conditioned"
    )
    max_gap_s: float = Field(0.01, ge=0, description="longer gaps (or lost-record runs) are an error")
    torque_lag_s: float | None = Field(
        None,
        description="the torque paired with a position sample is logged this much later; "
        "None: the log's own (one drive cycle for a run log, 0 for a CSV)",
    )
    stick_guard_s: float | None = Field(
        None, ge=0, description="rows this close to a joint's slow sample are rejected; default 1/cutoff_hz"
    )
    saturation_fraction: float = Field(
        0.995, gt=0, le=1, description="|τ| at or above this fraction of peak torque counts as saturated"
    )
    trim_s: float | None = Field(None, ge=0, description="trimmed at each end; default 2/cutoff_hz")

    @property
    def cutoff(self) -> float:
        """The cut-off in Hz (a resolved `auto`: see `with_cutoff`)."""
        if self.cutoff_hz == "auto":
            raise ValueError("cutoff_hz auto is resolved by choose_cutoff before processing")
        return float(self.cutoff_hz)

    @property
    def decimate(self) -> float:
        """The decimated sample rate, Hz (2 × the cut-off unless set)."""
        return 2.0 * self.cutoff if self.decimate_hz is None else float(self.decimate_hz)

    def with_cutoff(self, cutoff_hz: float) -> IdentifySettings:
        """These settings at a given cut-off (the decimation follows it unless set)."""
        return self.model_copy(update={"cutoff_hz": float(cutoff_hz)})
