"""`dynamics.yaml`: identified dynamics of one robot (kind `rxcomm/Dynamics`, architecture §7 identify).

What planners and `run` need is τ(q, q̇, q̈); the base parameters determine it completely. Each base
parameter stores its definition as a combination of named full parameters (p_b = Σ c_i·p_i, the
paper's regrouping), so a reader rebuilds a full parameter vector reproducing exactly these torques
(`rxcomm.model.base_parameters.load_dynamics`) without recomputing the QR. `full_parameters`, when present
(e.g. a physically consistent estimate), takes precedence.

Units: SI; parameter names as in `rxcomm.model.dynamics.parameter_names` (`joint_2.mcx` in kg·m,
`joint_3.Ixx` in kg·m² about the joint frame origin, `joint_4.rotor_inertia` motor side kg·m²,
`joint_1.fc` N·m, `joint_1.fv` N·m·s/rad, `joint_1.offset` N·m, `spring.k` N/m, `spring.kL0` N).
"""

from __future__ import annotations

from pydantic import Field, model_validator

from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict


class BaseParameterEstimate(Strict):
    name: str = Field(description="e.g. joint_2.mcz_R (suffix _R: other parameters are regrouped onto it)")
    label: str = Field(description="human-readable definition, e.g. 'joint_2.mcz + 0.625·joint_3.m + …'")
    independent: str = Field(description="the full parameter kept for it (coefficient 1 in `combination`)")
    combination: dict[str, float] = Field(description="full parameter name → coefficient")
    value: float = Field(description="estimate, SI units of the independent parameter")
    relative_std: float | None = Field(
        None,
        description="standard deviation / |value| from the least-squares covariance; None if not estimated",
    )

    @model_validator(mode="after")
    def _independent_in_combination(self) -> BaseParameterEstimate:
        if abs(self.combination.get(self.independent, 0.0) - 1.0) > 1e-12:
            raise ValueError(f"combination must contain {self.independent!r} with coefficient 1")
        return self


class BaseSetInfo(Strict):
    """How the base set was found (numerical QR on random states, `rxcomm.model.base_parameters`)."""

    n_full: int = Field(description="number of full parameters (regressor columns)")
    n_base: int
    rank_tolerance: float = Field(description="relative tolerance on the unit-column QR diagonal")
    r_min_kept: float = Field(description="smallest kept |R_ii| / |R_00| (unit columns)")
    r_max_dropped: float = Field(description="largest dropped |R_ii| / |R_00| (unit columns)")
    cond: float = Field(description="condition number of the unit-column base regressor on the random states")
    n_samples: int
    seed: int
    unidentifiable: list[str] = Field(description="parameters with no effect on the joint torques")


class JointFriction(Strict):
    joint: str
    coulomb_nm: float
    viscous_nm_s_per_rad: float
    offset_nm: float = Field(description="constant torque offset (sensor bias), N·m")
    motor_coulomb_nm: float | None = Field(
        None, description="Coulomb friction of this axis's motor, motor side, N·m (motor friction models)"
    )
    motor_viscous_nm_s_per_rad: float | None = Field(
        None, description="viscous friction of this axis's motor, motor side, N·m·s/rad"
    )


class SpringEstimate(Strict):
    """The balancer: τ_s = k·ab·sinθ − k·L0·ab·sinθ/L. The first term has the shape of link gravity and
    regroups with the spring link's first moment, so only k·L0 is identifiable on its own."""

    joint: str
    k_l0_n: float = Field(description="k·L0, N (identified)")
    k_l0_relative_std: float | None = None
    stiffness_n_per_m: float = Field(
        description="k, N/m: the prior when not identifiable alone (`stiffness_identified` false)"
    )
    stiffness_identified: bool = False


class Dynamics(Artefact):
    KIND = "rxcomm/Dynamics"
    SCHEMA_VERSION = 1
    REQUIRED_SUMMARY_KEYS = (
        "n_base_params",
        "validation_nrmse",
        "validation_rms_nm",
        "seconds",
    )

    robot: str = Field(description="robot name (URDF)")
    robot_joints: list[str]
    parameter_names: list[str] = Field(description="full parameter names, regressor column order")
    base_set: BaseSetInfo
    base_parameters: list[BaseParameterEstimate]
    full_parameters: dict[str, float] | None = Field(
        None, description="a full parameter estimate consistent with the base values (takes precedence)"
    )
    full_parameters_method: str | None = Field(None, description="how `full_parameters` was obtained")
    friction: list[JointFriction]
    spring: SpringEstimate | None = None

    @model_validator(mode="after")
    def _consistent(self) -> Dynamics:
        names = set(self.parameter_names)
        if len(names) != len(self.parameter_names):
            raise ValueError("parameter_names has duplicates")
        base_names = [b.name for b in self.base_parameters]
        if len(set(base_names)) != len(base_names):
            raise ValueError("base parameter names must be unique")
        if len(base_names) != self.base_set.n_base:
            raise ValueError(
                f"base_set.n_base is {self.base_set.n_base}, {len(base_names)} base parameters given"
            )
        for b in self.base_parameters:
            if unknown := [n for n in b.combination if n not in names]:
                raise ValueError(f"base parameter {b.name!r} uses unknown parameters {unknown}")
        if self.full_parameters is not None and set(self.full_parameters) != names:
            raise ValueError("full_parameters must hold exactly the names of parameter_names")
        if [f.joint for f in self.friction] != self.robot_joints:
            raise ValueError("friction must list robot_joints in order")
        return self
