"""`excitation.yaml`: an optimal exciting trajectory for dynamic identification (kind `rxcomm/Excitation`,
paper §4.2, architecture §7 excite).

Per joint j a finite Fourier series of `harmonics` terms with the common base frequency ω_f (paper
eq. 29, written with its velocity):

    q̇_j(t) = Σ_l a_jl·cos(l·ω_f·t) + b_jl·sin(l·ω_f·t)
    q_j(t)  = q0_j + Σ_l a_jl/(l·ω_f)·sin(l·ω_f·t) − b_jl/(l·ω_f)·cos(l·ω_f·t)

over one period T = 2π/ω_f (repeated `periods` times). It starts and ends at rest: the first
harmonic's coefficients are eliminated by Σ_l a_jl = 0 (q̇ = 0) and Σ_l l·b_jl = 0 (q̈ = 0) at t = 0
and t = T; `q_start_rad` = q(0) = q(T) = q0 − Σ_l b_l/(l·ω_f) is the rest pose `run` starts from.

The samples `run` executes are in the trajectory MCAP named by `trajectory_file` (kind
`rxcomm/Trajectory`, q, q̇, q̈ and τ_ff from the prior model at the drive cycle).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from rxcomm.schemas.envelope import Artefact, Sha256Hex
from rxcomm.schemas.strict import Strict


class ExcitationSettings(Strict):
    """Options of `rxcomm excite` (units in the names; fractions are of the robot's limits)."""

    harmonics: int = Field(5, ge=2, le=20, description="Fourier terms per joint (paper: N = 5)")
    omega_f_rad_s: float = Field(
        0.8, gt=0, description="base angular frequency (paper: 0.8 rad/s); snapped so T is whole drive cycles"
    )
    periods: int = Field(1, ge=1, le=20, description="periods in the executed trajectory")
    objective_samples: int = Field(
        80, ge=10, description="samples per period of the objective (paper: k = 80)"
    )
    check_samples: int = Field(
        1000, ge=400, description="samples per period on which the NLP constrains each limit's peaks"
    )
    objective: Literal["cond", "logdet"] = Field(
        "cond", description="cond: log cond(W) of the unit-column base regressor; logdet: −log det(WᵀW)/p"
    )
    starts: int = Field(4, ge=1, description="seeded random feasible starts; the best result is kept")
    seed: int = 0
    max_iterations: int = Field(150, ge=1, description="SLSQP iterations per start")
    tolerance: float = Field(1e-4, gt=0, description="SLSQP ftol on the objective (log cond)")
    baseline_trajectories: int = Field(
        10, ge=1, description="random feasible trajectories whose median cond is the baseline"
    )
    position_margin_rad: float = Field(0.05, ge=0, description="kept from each joint position limit")
    velocity_fraction: float = Field(0.95, gt=0, le=1)
    acceleration_fraction: float = Field(0.95, gt=0, le=1)
    torque_fraction: float = Field(
        0.8, gt=0, le=1, description="of peak torque, on the prior model (the real arm may be heavier)"
    )
    torque_rate_reserve: float = Field(
        0.2,
        ge=0,
        lt=1,
        description="of the torque-rate limit kept for the smooth dynamics where Coulomb friction reverses",
    )
    region_margin_m: float = Field(0.0, ge=0, description="kept inside each allowed-region box")
    min_rms_speed_rad_s: float = Field(
        0.15,
        ge=0,
        description="every joint's RMS speed at least this (at most ¼ of its velocity limit): cond(W) on "
        "unit columns cannot see a joint that barely moves, and identify rejects its slow rows",
    )
    coulomb_eps_rad_s: float = Field(
        0.05,
        gt=0,
        description="tanh width of the Coulomb column in the NLP objective (reported cond uses sign)",
    )
    start_rad: list[float] | None = Field(
        None, description="fixed rest pose q(0) = q(T); optimised (inside the limits and region) when None"
    )


class ExcitationStart(Strict):
    seed: int
    initial_cond: float = Field(description="cond of the random feasible starting trajectory")
    cond: float = Field(description="cond after optimisation and refinement (sign Coulomb, k samples)")
    feasible: bool = Field(description="every limit held on the dense check")
    iterations: int
    seconds: float


class ExcitationSummary(Strict):
    """What a rxcomm/Excitation summary holds (units in the names; None: not measured)."""

    cond: float | None = Field(description="required; None: not measured")
    cond_raw: float | None = Field(description="required; None: not measured")
    baseline_cond: float | None = Field(description="required; None: not measured")
    duration_s: float
    seconds: float | None = Field(description="required; None: not measured")
    max_limit_ratio: float | None = Field(description="required; None: not measured")
    cond_dense: float | None = None
    improvement_ratio: float | None = None
    worst_limit: str | None = None
    n_base_params: int | None = None
    starts_feasible: int | None = None


class Excitation(Artefact[ExcitationSettings, ExcitationSummary], kind="rxcomm/Excitation", schema_version=1):
    robot: str = Field(description="robot name (URDF)")
    robot_joints: list[str]
    harmonics: int
    omega_f_rad_s: float = Field(description="base frequency used (snapped to whole drive cycles per period)")
    period_s: float = Field(description="T = 2π/ω_f")
    periods: int
    q0_rad: list[float] = Field(description="Fourier offset per joint (paper eq. 29's q_i0)")
    q_start_rad: list[float] = Field(description="rest pose at t = 0 and at the end")
    a_rad_s: list[list[float]] = Field(description="cosine coefficients of q̇, joints × harmonics")
    b_rad_s: list[list[float]] = Field(description="sine coefficients of q̇, joints × harmonics")
    base_parameters: list[str] = Field(description="base parameters whose regressor columns W holds")
    starts: list[ExcitationStart]
    limit_ratios: dict[str, float] = Field(
        description="max value/limit per limit on the drive-cycle samples (robot limits, not the fractions)"
    )
    trajectory_file: str = Field(description="trajectory MCAP (kind rxcomm/Trajectory) beside this file")
    trajectory_sha256: Sha256Hex

    @model_validator(mode="after")
    def _shapes(self) -> Excitation:
        n = len(self.robot_joints)
        for name in ("q0_rad", "q_start_rad"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} must have {n} values")
        for name in ("a_rad_s", "b_rad_s"):
            c = getattr(self, name)
            if len(c) != n or any(len(row) != self.harmonics for row in c):
                raise ValueError(f"{name} must be {n} × {self.harmonics}")
        return self
