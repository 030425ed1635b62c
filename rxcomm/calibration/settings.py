"""`calibrate`'s settings (recorded in the Calibration artefact)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class CalibrateSettings(BaseModel):
    """Options of `calibrate` (the stage's settings, recorded in the artefact)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    holdout_fraction: float | None = Field(
        None,
        ge=0.0,
        lt=1.0,
        description="fraction of the fit-role poses held out (seeded); default 0 if the file has "
        "validation poses, else 0.25",
    )
    seed: int = 0
    loss: Literal["linear", "soft_l1", "huber", "cauchy"] = Field(
        "linear", description="robust loss on the weighted residuals (scale 3σ); linear = plain LM"
    )
    outlier_sigma: float = Field(
        5.0, gt=0, description="flag a pose with a residual beyond this many robust σ"
    )
    drop_outliers: bool = True
    position_sigma_m: float | None = Field(
        None, gt=0, description="tracker position noise (1σ, m); default the file's, else estimated"
    )
    orientation_sigma_rad: float | None = Field(
        None, gt=0, description="tracker orientation noise (1σ, rad); default the file's, else estimated"
    )
    point_in_tcp_m: tuple[float, float, float] | None = Field(
        None, description="measured point in the TCP frame (position-only probes); default the TCP origin"
    )
    max_iterations: int = Field(100, ge=1)
    cv_folds: int = Field(5, ge=2, description="folds of the cross-validation that chooses the model")
    model: Literal["auto", "frames", "offsets", "full", "full+compliance"] = Field(
        "auto", description="error model; auto: the richest model offered, regularised by the priors"
    )
    regularise: bool = Field(
        True,
        description="priors from manufacturing tolerances on the joint errors (calibration.priors): "
        "few noisy poses shrink toward the frames-only answer",
    )
    compliance: bool = Field(True, description="offer joint-compliance candidates to the model selection")
    undetermined_std_ratio: float = Field(
        5.0,
        gt=0,
        description="name a parameter whose σ at the TCP (m; rad × reach) exceeds this many position σ",
    )
