"""The robot's frame transforms along a run, for Foxglove's 3D panel: FK of the logged joints.

Each URDF link (and the TCP frame of drives.yaml) is given in its parent link, the tree the URDF
itself has, so Foxglove's URDF layer draws every link at its logged place. The actual robot uses the
URDF's link names; the commanded one the same tree with every frame prefixed ``demand/`` (its root at
the actual root), so a second URDF layer with that frame prefix shows it in the same 3D view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.model.robot import Robot

DEMAND_PREFIX = "demand/"


@dataclass(frozen=True)
class LinkTree:
    """(parent, child) frame names and Pinocchio frame ids of every link below the root and the TCP."""

    root: str
    pairs: tuple[tuple[str, str], ...]
    ids: tuple[tuple[int, int], ...]

    def prefixed(self, prefix: str) -> tuple[tuple[str, str], ...]:
        """The same tree under ``prefix`` (as a URDF layer's frame prefix names it), its root hung
        from the unprefixed root: the first pair is (root, prefix + root), at identity."""
        return ((self.root, prefix + self.root), *((prefix + a, prefix + b) for a, b in self.pairs))


def link_tree(robot: Robot) -> LinkTree:
    """The links of ``robot`` as the URDF chains them (fixed joints included) plus the TCP frame."""
    m = robot.model
    keep = [i for i, f in enumerate(m.frames) if f.type == pin.FrameType.BODY or i == robot.tcp_frame_id]

    def parent_link(i: int) -> int:
        j = m.frames[i].parentFrame
        while j > 0 and j not in keep:
            j = m.frames[j].parentFrame
        return j

    ids = [(parent_link(i), i) for i in keep if parent_link(i) > 0]
    root = next(m.frames[i].name for i in keep if parent_link(i) == 0)
    pairs = tuple((m.frames[a].name, m.frames[b].name) for a, b in ids)
    return LinkTree(root, pairs, tuple(ids))


def link_transforms(robot: Robot, tree: LinkTree, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of ``q`` [n, dof]: translation [n, m, 3] (m) and rotation x-y-z-w [n, m, 4] of every
    child in its parent (``tree.pairs`` order)."""
    m = robot.model
    data = robot.create_data()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    n, k = q.shape[0], len(tree.ids)
    trans, rot = np.zeros((n, k, 3)), np.zeros((n, k, 4))
    for r in range(n):
        pin.framesForwardKinematics(m, data, q[r])
        for c, (a, b) in enumerate(tree.ids):
            rel = data.oMf[a].actInv(data.oMf[b])
            trans[r, c] = rel.translation
            rot[r, c] = pin.Quaternion(rel.rotation).coeffs()  # x, y, z, w
    return trans, rot


def tcp_poses(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """TCP position [n, 3] (m) and orientation x-y-z-w [n, 4] in the base (root link) frame."""
    m = robot.model
    data = robot.create_data()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    pos, rot = np.zeros((len(q), 3)), np.zeros((len(q), 4))
    for r in range(len(q)):
        pin.framesForwardKinematics(m, data, q[r])
        f = data.oMf[robot.tcp_frame_id]
        pos[r], rot[r] = f.translation, pin.Quaternion(f.rotation).coeffs()
    return pos, rot
