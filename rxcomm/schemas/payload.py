"""`payload.yaml`: a payload identified on the flange (kind `rxcomm/Payload`, architecture §7).

Also the payload a simulated cell carries (`PayloadMount`, in `truth.yaml` and `run --truth-payload`).
Frames: the flange is the TCP's parent frame (`drives.yaml` tool.parent_frame); the centre of mass is
given in it, the inertia about the centre of mass in flange axes. Inertia tuples are in Pinocchio's
order Ixx Ixy Iyy Ixz Iyz Izz. plan-cp, plan-ptp, plan-cycles and run take the artefact as
`--payload` and add it to the last link (`rxcomm.model.payload`).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from rxcomm.schemas.dynamics import IdentifySettings
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.strict import Strict

Vec3 = tuple[float, float, float]
Inertia6 = tuple[float, float, float, float, float, float]


def inertia_matrix(i6: Inertia6 | list[float]) -> np.ndarray:
    """(Ixx Ixy Iyy Ixz Iyz Izz) → the symmetric 3 × 3 tensor."""
    xx, xy, yy, xz, yz, zz = i6
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], dtype=float)


def body_inertia_problem(i6: Inertia6 | list[float]) -> str | None:
    """Why no rigid body has this inertia about its centre of mass (None: one can)."""
    eig = np.linalg.eigvalsh(inertia_matrix(i6))
    tol = 1e-9 * max(1.0, float(np.abs(eig).max()))
    if eig[0] < -tol:
        return f"not positive semi-definite (principal moments {np.round(eig, 6).tolist()} kg·m²)"
    if 2.0 * eig.max() > eig.sum() + tol:
        return f"principal moments {np.round(eig, 6).tolist()} kg·m² break the triangle inequality"
    return None


class PayloadMount(Strict):
    """A rigid load on the flange: what the simulated cell carries (and what `--payload` adds)."""

    mass_kg: float = Field(gt=0, description="payload mass, kg")
    com_m: Vec3 = Field(description="centre of mass in the flange frame, m")
    inertia_com_kgm2: Inertia6 = Field(
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
        description="inertia about the centre of mass, flange axes, Ixx Ixy Iyy Ixz Iyz Izz, kg·m²",
    )

    @model_validator(mode="after")
    def _a_body(self) -> PayloadMount:
        if (why := body_inertia_problem(self.inertia_com_kgm2)) is not None:
            raise ValueError(f"inertia_com_kgm2 is no body's: {why}")
        return self


class CellPayload(Strict):
    """`run --truth-payload FILE`: the payload the simulated cell carries for one run (it replaces the
    truth file's `payload`; `payload: null` runs without one). Read by the cell only, never a stage."""

    kind: Literal["rxcomm/CellPayload"]
    schema_version: Literal[1]
    payload: PayloadMount | None


class PayloadFit(Strict):
    """The least-squares fit of the torque residual to the last link's 10 regressor columns."""

    log: str = Field(description="the excitation log (file name)")
    rows: int = Field(description="regressor rows used (sample × joint, joints near stiction left out)")
    cond: float = Field(description="condition number of the unit-column 10-column regressor")
    residual_rms_nm: list[float] = Field(description="per joint, after the fit, N·m")
    noise_weights_nm: list[float] = Field(description="per-joint residual σ that weighted the rows, N·m")


class PayloadValidation(Strict):
    """The identified payload on another motion: predicted (identified model + payload) vs measured."""

    log: str = Field(description="the validation log (file name)")
    rms_without_payload_nm: list[float | None] = Field(
        description="per joint, the identified robot model alone (moving rows; None: the joint did not move)"
    )
    rms_with_payload_nm: list[float | None] = Field(description="per joint, with the identified payload")
    total_rms_without_nm: float
    total_rms_with_nm: float


class ControllerPayload(Strict):
    """The payload as robot controllers take it: mass, centre of mass and inertia at the flange.

    `principal_*` is the form of controllers that want principal moments and the principal axes'
    orientation (e.g. ABB loaddata: mass, cog, aom, ix iy iz; KUKA LOAD_DATA: M, CM, J)."""

    mass_kg: float
    com_mm: Vec3 = Field(description="centre of mass in the flange frame, mm")
    inertia_com_kgm2: dict[str, float] = Field(
        description="about the centre of mass, flange axes: xx yy zz xy xz yz"
    )
    inertia_flange_kgm2: dict[str, float] = Field(
        description="about the flange origin, flange axes: xx yy zz xy xz yz"
    )
    principal_moments_kgm2: Vec3 = Field(description="about the centre of mass, ascending")
    principal_axes_wxyz: tuple[float, float, float, float] = Field(
        description="rotation flange → principal axes (columns: the eigenvectors, right-handed), "
        "quaternion w x y z"
    )
    physically_consistent: bool = Field(description="a body can have this inertia (PSD, triangle inequality)")


class PayloadSummary(Strict):
    """What a rxcomm/Payload summary holds (units in the names; None: not measured)."""

    mass_kg: float
    mass_std_kg: float | None = None
    com_m: Vec3
    com_std_m: Vec3 | None = None
    cond: float | None = None
    validation_rms_without_nm: float | None = Field(description="required; None: not measured")
    validation_rms_with_nm: float | None = Field(description="required; None: not measured")
    seconds: float | None = Field(description="required; None: not measured")


class Payload(Artefact[IdentifySettings, PayloadSummary], kind="rxcomm/Payload", schema_version=1):
    settings: IdentifySettings = Field(description="the identified model's processing the fit used")

    robot: str = Field(description="robot name (URDF)")
    flange_frame: str = Field(description="the frame mass and centre of mass are given in")
    mass_kg: float
    mass_std_kg: float
    com_m: Vec3
    com_std_m: Vec3
    inertia_com_kgm2: Inertia6 = Field(description="about the centre of mass, flange axes, Pinocchio order")
    inertia_com_std_kgm2: Inertia6
    inertial_parameters: list[float] = Field(
        description="the 10 parameters added to the last link (m, m·c, inertia about the joint origin; "
        "Pinocchio order, last joint's frame): what --payload adds"
    )
    fit: PayloadFit
    validation: PayloadValidation | None = Field(description="on another motion; None: no --validate log")
    controller: ControllerPayload
