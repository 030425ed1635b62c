"""ISO 9283:1998 performance criteria on attained poses and paths (vectorised numpy, no robot).

All positions in one frame (the robot base frame), metres; orientations as rotation matrices.

- Pose (§7.2.1, §7.2.2): over n cycles at one command pose, the barycentre x̄ = mean x_j of the
  attained positions; AP_p = |x̄ − x_c| (and its components AP_x, AP_y, AP_z); orientation deviations
  (a_j, b_j, c_j) = rotation vector of R_j·R_cᵀ (about the base x, y, z axes: the small-angle form
  of the standard's angle differences a_j − a_c …), AP_a = mean a_j …; RP_l = l̄ + 3 S_l with
  l_j = |x_j − x̄| and S_l = sqrt(Σ (l_j − l̄)² / (n − 1)); RP_a = 3 S_a … (S_a the sample std).
- Path (§8.2): at m points x_ci along the command path, the normal plane through x_ci; each cycle's
  attained path crosses it at x_ij (linear interpolation between samples; the crossing nearest
  x_ci); AT_p = max_i |x̄_i − x_ci| (x̄_i the barycentre of the n crossings); RT_p = max_i
  (l̄_i + 3 S_li) with l_ij = |x_ij − x̄_i|.
- Corner overshoot (§8.5): after each corner of the command path, the largest distance of the
  attained path from the command path within `zone_m` along the next edge; CO = the largest over
  corners and cycles.
- Path velocity (§8.7): v_j the mean attained speed of cycle j over the part where the command
  speed is at its plateau, v_c the command speed there; AV = (mean v_j − v_c) / v_c;
  RV = 3 S_v / v_c, S_v the sample std of the v_j (fractions; the standard prints them in %).

A quantity that cannot be computed (too few cycles for a standard deviation, no crossing) is None.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def _std(x: np.ndarray, axis: int = 0) -> np.ndarray | None:
    return None if x.shape[axis] < 2 else np.std(x, axis=axis, ddof=1)


@dataclass(frozen=True)
class PoseCriteria:
    n: int
    barycentre_m: np.ndarray
    AP_p: float
    AP_xyz: np.ndarray
    RP_l: float | None
    AP_abc: np.ndarray | None  # rad, None without orientation
    RP_abc: np.ndarray | None


def pose_criteria(
    attained_m: np.ndarray,
    command_m: np.ndarray,
    attained_rot: np.ndarray | None = None,
    command_rot: np.ndarray | None = None,
) -> PoseCriteria:
    """AP and RP at one command pose from n attained poses (`attained_m` [n, 3], `attained_rot`
    [n, 3, 3]; NaN rows, where the tracker saw nothing, are left out)."""
    x = np.asarray(attained_m, dtype=float)
    ok = np.all(np.isfinite(x), axis=1)
    x = x[ok]
    if len(x) == 0:
        raise ValueError("no attained pose")
    bary = x.mean(axis=0)
    d = bary - np.asarray(command_m, dtype=float)
    ell = np.linalg.norm(x - bary, axis=1)
    s_l = _std(ell)
    rp_l = None if s_l is None else float(ell.mean() + 3 * s_l)
    ap_abc = rp_abc = None
    if attained_rot is not None and command_rot is not None:
        r = np.asarray(attained_rot, dtype=float)[ok]
        if np.all(np.isfinite(r)):
            dev = Rotation.from_matrix(r @ np.asarray(command_rot, dtype=float).T).as_rotvec()
            ap_abc = dev.mean(axis=0)
            s = _std(dev)
            rp_abc = None if s is None else 3 * s
    return PoseCriteria(len(x), bary, float(np.linalg.norm(d)), d, rp_l, ap_abc, rp_abc)


def plane_crossings(path_m: np.ndarray, points_m: np.ndarray, tangents: np.ndarray) -> np.ndarray:
    """[m, 3]: where the polyline `path_m` [k, 3] crosses the plane through each of `points_m` [m, 3]
    normal to `tangents` [m, 3] — the crossing nearest the point (NaN where it never crosses)."""
    p = np.asarray(path_m, dtype=float)
    c = np.asarray(points_m, dtype=float)
    t = np.asarray(tangents, dtype=float)
    t = t / np.linalg.norm(t, axis=1, keepdims=True)
    s = p @ t.T - np.sum(c * t, axis=1)  # signed distances [k, m] (one matrix product)
    s0, s1 = s[:-1], s[1:]
    seg, plane = np.nonzero((s0 <= 0) & (s1 > 0) | (s0 >= 0) & (s1 < 0))  # the few sign changes
    out = np.full(c.shape, np.nan)
    if seg.size == 0:
        return out
    a, b = s0[seg, plane], s1[seg, plane]
    x = p[seg] + (a / (a - b))[:, None] * (p[seg + 1] - p[seg])
    d = np.linalg.norm(x - c[plane], axis=1)
    order = np.lexsort((d, plane))  # by plane, nearest first
    first = order[np.r_[True, plane[order][1:] != plane[order][:-1]]]
    out[plane[first]] = x[first]
    return out


@dataclass(frozen=True)
class PathCriteria:
    n: int  # cycles
    AT_p: float
    RT_p: float | None
    deviation_m: np.ndarray  # [m] |x̄_i − x_ci| along the path
    barycentres_m: np.ndarray  # [m, 3]


def path_criteria(command_m: np.ndarray, tangents: np.ndarray, cycles: list[np.ndarray]) -> PathCriteria:
    """AT_p and RT_p from the attained paths of n cycles (each [k_j, 3]) at the m command points
    `command_m` [m, 3] with unit tangents `tangents` [m, 3]. Points no cycle crosses are left out."""
    xs = np.array([plane_crossings(c, command_m, tangents) for c in cycles])  # [n, m, 3]
    ok = np.all(np.isfinite(xs), axis=(0, 2))  # a plane every cycle crosses
    if not ok.any():
        raise ValueError("no command point's normal plane is crossed by every cycle")
    xs = xs[:, ok]
    bary = xs.mean(axis=0)
    dev = np.linalg.norm(bary - np.asarray(command_m)[ok], axis=1)
    ell = np.linalg.norm(xs - bary[None], axis=2)  # [n, m]
    s_l = _std(ell)
    rt = None if s_l is None else float(np.max(ell.mean(axis=0) + 3 * s_l))
    return PathCriteria(len(cycles), float(dev.max()), rt, dev, bary)


def distances_to_polyline(points_m: np.ndarray, polyline_m: np.ndarray, chunk: int = 2048) -> np.ndarray:
    """[k]: the distance of each point to a densely sampled curve `polyline_m` [m, 3] (segments)."""
    a, b = polyline_m[:-1], polyline_m[1:]
    ab = b - a
    ab2 = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    out = np.empty(len(points_m))
    for lo in range(0, len(points_m), chunk):
        p = points_m[lo : lo + chunk, None, :]
        u = np.clip(np.sum((p - a) * ab, axis=2) / ab2, 0.0, 1.0)
        out[lo : lo + chunk] = np.min(np.linalg.norm(p - (a + u[..., None] * ab), axis=2), axis=1)
    return out


def corner_overshoot(
    command_polyline_m: np.ndarray,
    corners_m: np.ndarray,
    next_edges: np.ndarray,
    cycles: list[np.ndarray],
    zone_m: float,
) -> tuple[float, np.ndarray]:
    """(CO, [n_corners] per corner, max over cycles): the largest distance of the attained points
    from the command path within `zone_m` after each corner along its next edge (unit directions
    `next_edges` [c, 3]); points beside the corner's incoming edge are not in the zone. Only the
    command path within 2 `zone_m` of the corner is searched."""
    e = next_edges / np.linalg.norm(next_edges, axis=1, keepdims=True)
    per = np.zeros(len(corners_m))
    for i, (corner, ei) in enumerate(zip(corners_m, e, strict=True)):
        near = np.linalg.norm(command_polyline_m - corner, axis=1) <= 2 * zone_m
        local = command_polyline_m[np.flatnonzero(near).min() : np.flatnonzero(near).max() + 1]
        for path in cycles:
            rel = path - corner
            along = rel @ ei
            across = np.linalg.norm(rel - along[:, None] * ei, axis=1)
            zone = (along >= 0) & (along <= zone_m) & (across <= zone_m)
            if zone.any():
                per[i] = max(per[i], float(np.max(distances_to_polyline(path[zone], local))))
    return float(per.max()), per


@dataclass(frozen=True)
class VelocityCriteria:
    n: int
    command_speed_m_per_s: float
    mean_speeds_m_per_s: np.ndarray  # v_j per cycle
    AV: float
    RV: float | None


def velocity_criteria(
    attained_speeds: list[np.ndarray], command_speeds: list[np.ndarray], plateau: float = 0.98
) -> VelocityCriteria:
    """AV and RV from n cycles: per cycle the attained speed samples and the command speed at the
    same instants (m/s); the plateau is where the command speed is ≥ `plateau` × its maximum."""
    v_c_all, v_j = [], []
    for v_att, v_cmd in zip(attained_speeds, command_speeds, strict=True):
        on = v_cmd >= plateau * np.max(v_cmd)
        on &= np.isfinite(v_att)
        if not on.any():
            raise ValueError("no samples on the command speed's plateau")
        v_c_all.append(np.median(v_cmd[on]))
        v_j.append(np.mean(v_att[on]))
    v_c = float(np.median(v_c_all))
    v = np.array(v_j)
    s = _std(v)
    return VelocityCriteria(
        len(v), v_c, v, float((v.mean() - v_c) / v_c), None if s is None else float(3 * s / v_c)
    )
