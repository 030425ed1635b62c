"""`rxcomm/Payload`'s contents from an identified payload (`rxcomm.identification.payload`): the estimate
± σ, the fit, the validation and the forms controllers take (`rxcomm.schemas.payload`)."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from rxcomm.identification.payload import PayloadResult
from rxcomm.identification.settings import MODEL_SETTINGS, IdentifySettings
from rxcomm.identification.validation import Validation
from rxcomm.io.validate import settings_from_options
from rxcomm.model.payload import FlangeInertia
from rxcomm.model.robot import Robot
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.payload import (
    ControllerPayload,
    PayloadFit,
    PayloadValidation,
    body_inertia_problem,
)


def model_settings(art: Dynamics) -> IdentifySettings:
    """The identified model's own processing (cut-off, decimation, friction model, lag): the payload's
    residual is seen through the same filter as the model was fitted through."""
    values = {k: getattr(art.settings, k) for k in MODEL_SETTINGS if getattr(art.settings, k) is not None}
    if values.get("cutoff_hz", "auto") == "auto":
        values["cutoff_hz"] = art.summary.cutoff_hz if art.summary.cutoff_hz is not None else 10.0
    return settings_from_options(IdentifySettings, values)


def _tensor(i: np.ndarray) -> dict[str, float]:
    return {
        k: float(i[a, b])
        for k, (a, b) in {
            "xx": (0, 0),
            "yy": (1, 1),
            "zz": (2, 2),
            "xy": (0, 1),
            "xz": (0, 2),
            "yz": (1, 2),
        }.items()
    }


def controller_form(load: FlangeInertia) -> ControllerPayload:
    """Mass, centre of mass (mm) and inertia at the flange: about the centre of mass and about the flange
    origin in flange axes, and as principal moments with the principal axes' orientation."""
    ic, c, m = load.inertia_com_kgm2, np.asarray(load.com_m), load.mass_kg
    io = ic + m * (float(c @ c) * np.eye(3) - np.outer(c, c))  # parallel axes
    eig, vec = np.linalg.eigh(ic)
    if np.linalg.det(vec) < 0:
        vec[:, 2] = -vec[:, 2]
    q = pin.Quaternion(vec)
    wxyz = (float(q.w), float(q.x), float(q.y), float(q.z))
    if wxyz[0] < 0:
        wxyz = tuple(-v for v in wxyz)
    return ControllerPayload(
        mass_kg=m,
        com_mm=tuple(float(v) * 1e3 for v in c),
        inertia_com_kgm2=_tensor(ic),
        inertia_flange_kgm2=_tensor(io),
        principal_moments_kgm2=tuple(float(v) for v in eig),
        principal_axes_wxyz=wxyz,
        physically_consistent=body_inertia_problem(load.inertia6) is None,
    )


def _rms(v: Validation) -> list[float | None]:
    return [None if not np.isfinite(x) else float(x) for x in v.rms_nm]


def validation_fields(result: PayloadResult) -> PayloadValidation | None:
    if result.without is None or result.with_payload is None:
        return None
    return PayloadValidation(
        log=result.without.source.removeprefix("log: "),
        rms_without_payload_nm=_rms(result.without),
        rms_with_payload_nm=_rms(result.with_payload),
        total_rms_without_nm=result.without.total_rms_moving_nm,
        total_rms_with_nm=result.with_payload.total_rms_moving_nm,
    )


def payload_fields(robot: Robot, result: PayloadResult, log_name: str) -> dict:
    """The data fields of a `rxcomm/Payload` artefact (everything but the envelope)."""
    load = result.load
    return {
        "robot": robot.name,
        "flange_frame": robot.model.frames[robot.flange_frame_id].name,
        "mass_kg": load.mass_kg,
        "mass_std_kg": result.mass_std_kg,
        "com_m": tuple(load.com_m),
        "com_std_m": tuple(result.com_std_m),
        "inertia_com_kgm2": load.inertia6,
        "inertia_com_std_kgm2": tuple(result.inertia_std_kgm2),
        "inertial_parameters": [float(v) for v in result.inertial],
        "fit": PayloadFit(
            log=log_name,
            rows=result.rows,
            cond=result.cond,
            residual_rms_nm=[float(v) for v in result.residual_rms_nm],
            noise_weights_nm=[float(v) for v in result.noise_weights_nm],
        ),
        "validation": validation_fields(result),
        "controller": controller_form(load),
    }


def payload_summary(result: PayloadResult) -> dict[str, object]:
    """The architecture §9 summary: the estimate, the validation with and without it ("not measured"
    without a validation log), the time."""
    val = validation_fields(result)

    def total(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else float(x)

    return {
        "mass_kg": result.load.mass_kg,
        "mass_std_kg": result.mass_std_kg,
        "com_m": [float(v) for v in result.load.com_m],
        "com_std_m": [float(v) for v in result.com_std_m],
        "cond": result.cond,
        "validation_rms_without_nm": None if val is None else total(val.total_rms_without_nm),
        "validation_rms_with_nm": None if val is None else total(val.total_rms_with_nm),
        "seconds": result.seconds,
    }
