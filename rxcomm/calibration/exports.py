"""The calibrated kinematics in the forms a controller takes: modified DH parameters (plain, and with
Hayati's β where plain MDH cannot follow a calibrated parallel pair), the joint zero-offset table,
and what each form leaves of the calibration (`rxcomm.schemas.kinematics` documents the artefact).

Both forms are least-squares fits of the MDH FK to the calibrated model's rigid FK
(`rxcomm.model.mdh.fit_mdh`) on `FIT_POSES` random poses within the joint limits, and the residual
stated is the max over `CHECK_POSES` other random poses, so it is a measured figure, not the fit's
own. Written as YAML (`rxcomm/Kinematics`) and as a CSV beside it.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import pinocchio as pin

from rxcomm.io.files import atomic_write_text
from rxcomm.io.yaml_io import write_yaml_artefact
from rxcomm.model.geometric_errors import ErrorModel, characteristic_length_m, random_poses, se3_to_xyz_rpy
from rxcomm.model.mdh import FIELDS, Mdh, fit_mdh, mdh_from_robot, residual
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import Placement
from rxcomm.schemas.kinematics import Kinematics, MdhForm, MdhJoint, ZeroOffset

FIT_POSES, CHECK_POSES = 64, 200
CONVENTION = (
    "Craig modified DH: T_i = Rx(alpha_{i-1}) Ry(beta_{i-1}) Tx(a_{i-1}) Rz(q_i + theta_offset_i) Tz(d_i); "
    "TCP in the base frame = base * T_1 * ... * T_n * tool; beta = 0 in plain MDH; base and tool "
    "rpy_rad = [roll, pitch, yaw] about the fixed X, Y, Z axes, R = Rz(yaw) Ry(pitch) Rx(roll) (URDF)"
)


def _placement(m: pin.SE3) -> Placement:
    xyz, rpy = se3_to_xyz_rpy(m)
    return Placement(xyz_m=tuple(xyz), rpy_rad=tuple(rpy))


def _form(robot: Robot, target: Robot, mdh: Mdh, check: np.ndarray, length_m: float) -> MdhForm:
    dp, do = residual(target, mdh, check, length_m)
    joints = [
        MdhJoint(joint=name, **{f: float(getattr(r, f)) for f in FIELDS})
        for name, r in zip(robot.joint_names, mdh.rows, strict=True)
    ]
    return MdhForm(
        base=_placement(mdh.base),
        joints=joints,
        tool=_placement(mdh.tool),
        max_position_residual_m=dp,
        max_orientation_residual_rad=do,
    )


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def zero_offsets(robot: Robot, nominal: Mdh, calibrated: Mdh) -> list[ZeroOffset]:
    """Calibrated − nominal θ_offset per joint. Joint 1's and the last joint's θ_offset are fixed by
    the convention, so their zero shows as the base's (frame 0) and the tool's rotation about their
    axis: that rotation is reported, with a note."""
    n = robot.n
    out = []
    for j, name in enumerate(robot.joint_names):
        note = None
        if j == 0:
            off = float(pin.log3(nominal.base.rotation.T @ calibrated.base.rotation)[2])
            note = "the base's rotation about axis 1 (not separable from a joint-1 zero offset)"
        elif j == n - 1:
            off = float(pin.log3(calibrated.tool.rotation @ nominal.tool.rotation.T)[2])
            note = f"the tool's rotation about axis {n} (not separable from a joint-{n} zero offset)"
        else:
            off = _wrap(calibrated.rows[j].theta_offset_rad - nominal.rows[j].theta_offset_rad)
        out.append(ZeroOffset(joint=name, offset_rad=off, offset_deg=float(np.degrees(off)), note=note))
    return out


def kinematics_artefact(
    robot: Robot, errors: ErrorModel, inputs: dict[str, Path], seed: int = 0
) -> Kinematics:
    """The MDH forms and zero offsets of `robot` with `errors` (rigid: compliance is not in them)."""
    calibrated = errors.apply(robot)
    rng = np.random.default_rng(seed)
    fit_q, check_q = random_poses(robot, FIT_POSES, rng), random_poses(robot, CHECK_POSES, rng)
    length = characteristic_length_m(robot)
    nominal = mdh_from_robot(robot)
    plain = fit_mdh(robot, calibrated, fit_q, length, beta=False)
    hayati = fit_mdh(robot, calibrated, fit_q, length, beta=True)
    forms = {k: _form(robot, calibrated, m, check_q, length) for k, m in (("mdh", plain), ("beta", hayati))}
    nominal_form = _form(robot, robot, nominal, check_q, length)
    names = robot.joint_names
    pairs = [(names[i], names[j]) for i, j in nominal.parallel]
    notes = []
    if pairs:
        notes.append(
            "plain MDH cannot follow the calibrated tilt between the parallel axes "
            + ", ".join(f"{a}/{b}" for a, b in pairs)
            + f": it leaves {forms['mdh'].max_position_residual_m * 1e3:.3g} mm / "
            f"{forms['mdh'].max_orientation_residual_rad * 1e3:.3g} mrad; with Hayati's β "
            f"{forms['beta'].max_position_residual_m * 1e3:.3g} mm"
        )
    summary = {
        "mdh_max_position_residual_m": forms["mdh"].max_position_residual_m,
        "mdh_max_orientation_residual_rad": forms["mdh"].max_orientation_residual_rad,
        "mdh_beta_max_position_residual_m": forms["beta"].max_position_residual_m,
        "mdh_beta_max_orientation_residual_rad": forms["beta"].max_orientation_residual_rad,
        "n_sample_poses": CHECK_POSES,
    }
    settings = {"fit_poses": FIT_POSES, "check_poses": CHECK_POSES, "seed": seed, "length_m": length}
    return Kinematics(
        **Kinematics.envelope(inputs, settings, summary),
        robot=robot.name,
        joint_names=list(names),
        convention=CONVENTION,
        parallel_pairs=pairs,
        mdh=forms["mdh"],
        mdh_beta=forms["beta"],
        nominal=nominal_form,
        zero_offsets=zero_offsets(robot, nominal, plain),
        notes=notes,
    )


def kinematics_csv(art: Kinematics) -> str:
    """The table as CSV: `#` lines state the convention, base, tool and residuals; one row per joint
    and form (mdh, mdh_beta, nominal) with the zero offset on the mdh rows."""
    buf = io.StringIO()
    sources = ", ".join(f"{k} sha256 {v}" for k, v in art.inputs.items()) or "none recorded"
    buf.write(f"# {art.kind} of robot {art.robot} (rxcomm {art.rxcomm_version}); inputs: {sources}\n")
    buf.write(f"# {art.convention}\n")
    for key, form in (("mdh", art.mdh), ("mdh_beta", art.mdh_beta), ("nominal", art.nominal)):
        for frame in ("base", "tool"):
            p = getattr(form, frame)
            buf.write(f"# {key} {frame}: xyz_m {list(p.xyz_m)} rpy_rad {list(p.rpy_rad)}\n")
        buf.write(
            f"# {key} residual: max position {form.max_position_residual_m:.6g} m, max orientation "
            f"{form.max_orientation_residual_rad:.6g} rad over {art.summary.n_sample_poses} poses\n"
        )
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["form", "joint", *FIELDS, "zero_offset_rad", "zero_offset_deg"])
    zero = {z.joint: z for z in art.zero_offsets}
    for key, form in (("mdh", art.mdh), ("mdh_beta", art.mdh_beta), ("nominal", art.nominal)):
        for j in form.joints:
            z = zero[j.joint] if key == "mdh" else None
            extra = ["", ""] if z is None else [repr(z.offset_rad), repr(z.offset_deg)]
            w.writerow([key, j.joint, *(repr(getattr(j, f)) for f in FIELDS), *extra])
    return buf.getvalue()


def export_kinematics_csv(source: Path, out: Path) -> Path:
    """`rxcomm export mdh.yaml`: the CSV of a `rxcomm/Kinematics` artefact (what `--mdh-out` writes
    beside it)."""
    from rxcomm.io.yaml_io import read_yaml_artefact

    return atomic_write_text(out, kinematics_csv(read_yaml_artefact(source, Kinematics)))


def write_kinematics(path: str | Path, art: Kinematics) -> tuple[Path, Path]:
    """`path` (YAML) and the CSV beside it (same name, .csv)."""
    path = Path(path)
    write_yaml_artefact(path, art)
    csv_path = path.with_suffix(".csv")
    atomic_write_text(csv_path, kinematics_csv(art))
    return path, csv_path
