"""Arms the project does not ship, for the IK's tests: a sample robot's directory with the joints of
its URDF rewritten (other lengths, axis signs, frame conventions), read by `load_robot` as usual."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pinocchio as pin

# (origin xyz in m, origin rotation, axis) of each joint in chain order: six revolute, then the flange
Joint = tuple[np.ndarray, np.ndarray, np.ndarray]

_BLOCK = re.compile(r'(<joint name="[^"]+" type="(?:revolute|fixed)">)(.*?)(</joint>)', re.S)


def _floats(text: str) -> np.ndarray:
    return np.array(text.split(), dtype=float)


def _fmt(v: np.ndarray) -> str:
    return " ".join(f"{x:.17g}" for x in v)


def read_joints(urdf: str) -> list[Joint]:
    out = []
    for m in _BLOCK.finditer(urdf):
        origin = re.search(r'<origin xyz="([^"]+)" rpy="([^"]+)"', m.group(2))
        axis = re.search(r'<axis xyz="([^"]+)"', m.group(2))
        rot = pin.rpy.rpyToMatrix(_floats(origin.group(2)))
        out.append((_floats(origin.group(1)), rot, _floats(axis.group(1)) if axis else np.zeros(3)))
    return out


def write_arm(src: Path, dst: Path, joints: list[Joint], limit_rad: float = np.pi) -> Path:
    """``src``'s robot directory copied to ``dst`` with its joints set to ``joints`` (revolute limits
    ±``limit_rad``); returns ``dst``."""
    dst.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        if f.is_file():
            shutil.copy(f, dst / f.name)
    urdf_path = next(dst.glob("*.urdf"))
    it = iter(joints)

    def rewrite(m: re.Match) -> str:
        xyz, rot, axis = next(it)
        body = re.sub(
            r"<origin [^>]*/>",
            f'<origin xyz="{_fmt(xyz)}" rpy="{_fmt(pin.rpy.matrixToRpy(rot))}"/>',
            m.group(2),
            count=1,
        )
        body = re.sub(r"<axis [^>]*/>", f'<axis xyz="{_fmt(axis)}"/>', body)
        body = re.sub(r'lower="[^"]+" upper="[^"]+"', f'lower="{-limit_rad}" upper="{limit_rad}"', body)
        return m.group(1) + body + m.group(3)

    urdf_path.write_text(_BLOCK.sub(rewrite, urdf_path.read_text()))
    return dst


def reframed(joints: list[Joint], rng: np.random.Generator) -> list[Joint]:
    """The same arm in other URDF conventions: each joint frame turned by a random rotation (the next
    origin compensates, so the links do not move) and each axis sign drawn at random (q_i → ±q_i)."""
    out = list(joints)
    for k in range(6):
        s = pin.exp3(rng.normal(0.0, 1.5, 3))
        xyz, rot, axis = out[k]
        out[k] = (xyz, rot @ s, rng.choice([-1.0, 1.0]) * (s.T @ axis))
        nxyz, nrot, naxis = out[k + 1]
        out[k + 1] = (s.T @ nxyz, s.T @ nrot, naxis)
    return out


def _j(xyz, axis, rpy=(0.0, 0.0, 0.0)) -> Joint:
    return np.array(xyz, float), pin.rpy.rpyToMatrix(np.array(rpy, float)), np.array(axis, float)


# A KUKA-like arm in ROS-Industrial conventions: axis 1 pointing down, the arm along x, shoulder offset
# and a step between axes 3 and 4, the flange turned onto x.
KUKA_LIKE = [
    _j((0, 0, 0.4), (0, 0, -1)),
    _j((0.025, 0, 0), (0, 1, 0)),
    _j((0.455, 0, 0), (0, 1, 0)),
    _j((0, 0, 0.035), (-1, 0, 0)),
    _j((0.42, 0, 0), (0, 1, 0)),
    _j((0.08, 0, 0), (-1, 0, 0)),
    _j((0, 0, 0), (0, 0, 0), (0, np.pi / 2, 0)),
]

# A UR-like arm (axes 2, 3, 4 parallel, wrist axes offset): no spherical wrist, no closed form here.
UR_LIKE = [
    _j((0, 0, 0.089159), (0, 0, 1)),
    _j((0, 0.13585, 0), (0, 1, 0), (0, np.pi / 2, 0)),
    _j((0, -0.1197, 0.425), (0, 1, 0)),
    _j((0, 0, 0.39225), (0, 1, 0), (0, np.pi / 2, 0)),
    _j((0, 0.093, 0), (0, 0, 1)),
    _j((0, 0, 0.09465), (0, 1, 0)),
    _j((0, 0.0823, 0), (0, 0, 0), (0, 0, np.pi / 2)),
]


def lateral_offset(joints: list[Joint], b_m: float) -> list[Joint]:
    """``joints`` with axis 3 moved ``b_m`` along axis 2 (a Stäubli-TX-like lateral offset, OPW's b)."""
    out = list(joints)
    xyz, rot, axis = out[2]
    out[2] = (xyz + b_m * axis / np.linalg.norm(axis), rot, axis)
    return out
