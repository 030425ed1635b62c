"""Parity of an exported kinematic model: the file read back by a reader that shares no code with
rxcomm's kinematics, its TCP forward kinematics against the calibrated model's (Pinocchio), over
`PARITY_POSES` random poses within the joint limits.

Readers: a URDF is parsed by ROS's own parser (``urdf_parser_py``, package ``urdfdom-py``) and its
chain composed by the URDF specification's formula, T = Π origin(xyz, rpy) · R(axis, q), rpy as
R = Rz(yaw)·Ry(pitch)·Rx(roll); an MDH/Hayati table by Craig's formula Rx(α)·Ry(β)·Tx(a)·Rz(q+θ)·Tz(d);
a joint-origin table by the URDF formula on its rows. All in plain numpy here, from the file's text.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rxcomm.model.geometric_errors import predict_poses, random_poses
from rxcomm.model.robot import Robot

PARITY_POSES = 256
PARITY_SEED = 31
HOLD_M = 1e-6  # a format holds the calibration when its FK stays within 1 µm of it


@dataclass(frozen=True)
class Parity:
    """The exported model's TCP against the calibrated one's, max over ``n_poses`` poses."""

    reader: str
    n_poses: int
    max_position_m: float
    max_orientation_rad: float

    @property
    def holds(self) -> bool:
        return self.max_position_m <= HOLD_M

    def as_dict(self) -> dict[str, Any]:
        return {
            "reader": self.reader,
            "n_poses": self.n_poses,
            "max_position_m": self.max_position_m,
            "max_orientation_rad": self.max_orientation_rad,
            "holds_1um": self.holds,
        }

    def text(self) -> str:
        return (
            f"max {self.max_position_m * 1e6:.3g} µm / {self.max_orientation_rad * 1e6:.3g} µrad over "
            f"{self.n_poses} poses ({self.reader})"
        )


def rot_x(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a: np.ndarray) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def hom(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """[..., 4, 4] from rotations [..., 3, 3] and translations [..., 3]."""
    rotation = np.asarray(rotation, dtype=float)
    out = np.zeros((*rotation.shape[:-2], 4, 4))
    out[..., :3, :3] = rotation
    out[..., :3, 3] = translation
    out[..., 3, 3] = 1.0
    return out


def origin(xyz: Any, rpy: Any) -> np.ndarray:
    """URDF ``<origin>``: translation xyz, rotation R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    r, p, y = (np.asarray(float(v)) for v in rpy)
    return hom(rot_z(y) @ rot_y(p) @ rot_x(r), np.asarray(xyz, dtype=float))


def axis_rotation(axis: Any, q: np.ndarray) -> np.ndarray:
    """[N, 4, 4] rotations by q [N] about the unit ``axis`` (Rodrigues)."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    s, c = np.sin(q)[:, None, None], np.cos(q)[:, None, None]
    return hom(np.eye(3) + s * kx + (1 - c) * (kx @ kx), np.zeros((q.shape[0], 3)))


def compare(reader: str, robot: Robot, calibrated: Robot, qs: np.ndarray, t: np.ndarray) -> Parity:
    """Parity of the TCP placements ``t`` [N, 4, 4] (robot's base frame) against ``calibrated``'s."""
    p, r = predict_poses(calibrated, qs)
    dp = np.linalg.norm(t[:, :3, 3] - p, axis=1)
    rel = np.einsum("nji,njk->nik", r, t[:, :3, :3])
    w = 0.5 * np.stack(
        [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], 1
    )
    ang = np.arctan2(np.linalg.norm(w, axis=1), 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1))
    return Parity(reader, int(qs.shape[0]), float(dp.max()), float(ang.max()))


def parity_poses(robot: Robot) -> np.ndarray:
    return random_poses(robot, PARITY_POSES, np.random.default_rng(PARITY_SEED))


# ---------------------------------------------------------------- the readers


def urdf_fk(urdf_text: str, joint_names: list[str], tip_link: str, qs: np.ndarray) -> np.ndarray:
    """[N, 4, 4] of ``tip_link`` in the root link's frame, the URDF parsed by ``urdf_parser_py``."""
    from urdf_parser_py.urdf import URDF

    model = URDF.from_xml_string(urdf_text.encode())
    chain = model.get_chain(model.get_root(), tip_link, joints=True, links=False, fixed=True)
    t = np.broadcast_to(np.eye(4), (qs.shape[0], 4, 4)).copy()
    for name in chain:
        j = model.joint_map[name]
        o = j.origin
        t = t @ origin(o.xyz if o is not None else (0, 0, 0), o.rpy if o is not None else (0, 0, 0))
        if j.type in ("revolute", "continuous"):
            t = t @ axis_rotation(j.axis if j.axis is not None else (1, 0, 0), qs[:, joint_names.index(name)])
        elif j.type != "fixed":
            raise ValueError(f"joint {name}: type {j.type} is not in a 6R arm")
    return t


def mdh_fk(table: dict[str, Any], qs: np.ndarray) -> np.ndarray:
    """[N, 4, 4] TCP of an MDH/Hayati table (:mod:`rxcomm.calibration.controller_files`' layout):
    base · Π Rx(α)·Ry(β)·Tx(a)·Rz(q + θ_offset)·Tz(d) · tool."""
    n = qs.shape[0]
    base, tool = table["base"], table["tool"]
    t = np.broadcast_to(origin(base["xyz_m"], base["rpy_rad"]), (n, 4, 4)).copy()
    for i, row in enumerate(table["joints"]):
        alpha, beta = np.asarray(float(row["alpha_rad"])), np.asarray(float(row.get("beta_rad", 0.0)))
        fixed = hom(rot_x(alpha) @ rot_y(beta), np.zeros(3)) @ hom(np.eye(3), [float(row["a_m"]), 0, 0])
        theta = qs[:, i] + float(row["theta_offset_rad"])
        t = t @ fixed @ hom(rot_z(theta), np.zeros((n, 3))) @ hom(np.eye(3), [0, 0, float(row["d_m"])])
    return t @ origin(tool["xyz_m"], tool["rpy_rad"])


def origins_fk(table: dict[str, Any], qs: np.ndarray) -> np.ndarray:
    """[N, 4, 4] TCP of a joint-origin table: Π origin(xyz, rpy)·R(axis, q) · tool (URDF formula)."""
    t = np.broadcast_to(np.eye(4), (qs.shape[0], 4, 4)).copy()
    for i, row in enumerate(table["joints"]):
        t = t @ origin(row["xyz_m"], row["rpy_rad"]) @ axis_rotation(row["axis"], qs[:, i])
    tool = table["tool"]
    return t @ origin(tool["xyz_m"], tool["rpy_rad"])
