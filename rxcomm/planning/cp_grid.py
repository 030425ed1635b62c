"""Where the timing of a fixed joint path puts its nodes (paper §5.1–5.3): toppra's grid, the NLP's grid.

A time-optimal profile rides one limit between switch points and changes σ̈ abruptly at them; a
piecewise-polynomial σ̈ can follow only as fast as the grid allows. So toppra's grid is dense where the
joint path bends, the NLP's where toppra's profile spends its time and around its switch points, with
constant-jerk end ramps as short as the torque rate allows and a node on every joint reversal.
"""

from __future__ import annotations

import numpy as np

from rxcomm.planning.path_dynamics import PathDynamics
from rxcomm.planning.path_ik import JointPath
from rxcomm.planning.path_nlp import S_MIN, coulomb_levels
from rxcomm.planning.path_profile import PathProfile
from rxcomm.planning.topp import PlanLimits


def reversal_points(jp: JointPath) -> np.ndarray:
    """σ where some joint's q' changes sign (the joint reverses; smooth Coulomb friction peaks there)."""
    s = np.linspace(0, jp.length_m, max(4 * len(jp.sigma), 400))
    qs = jp(s, 1)
    out = []
    for j in range(qs.shape[1]):
        if np.abs(qs[:, j]).max() < 1e-4:  # a joint that does not move has no reversal (only noise)
            continue
        idx = np.flatnonzero(np.sign(qs[:-1, j]) * np.sign(qs[1:, j]) < 0)
        for i in idx:
            a, b = qs[i, j], qs[i + 1, j]
            out.append(s[i] + (s[i + 1] - s[i]) * a / (a - b))
    return np.sort(np.array(out))


def switch_points(
    profile: PathProfile, jp: JointPath, limits: PlanLimits, pd: PathDynamics | None
) -> np.ndarray:
    """σ where the profile switches: σ̈ changes sign or another (limit, joint) becomes the binding one.

    Between such points a time-optimal profile rides one constraint; at them a continuous σ̈ needs
    a transition that only a fine grid keeps short."""
    g = profile.sigma
    sd, sdd = profile.sd, profile.sdd
    qs, qss = jp(g, 1), jp(g, 2)
    parts = [
        np.abs(qs) * sd[:, None] / limits.v_max,
        np.abs(qss * sd[:, None] ** 2 + qs * sdd[:, None]) / limits.a_max,
    ]
    if pd is not None:
        parts.append(np.abs(pd.torque(sdd, sd)) / limits.tau_max)
    binding = np.argmax(np.hstack(parts), axis=1)
    change = (binding[1:] != binding[:-1]) | (np.sign(sdd[1:]) * np.sign(sdd[:-1]) < 0)
    idx = np.flatnonzero(change[1:-1]) + 1  # not the rest-to-rest ends
    return (g[idx] + g[idx + 1]) / 2


def toppra_grid(jp: JointPath, intervals: int, a_max: np.ndarray) -> np.ndarray:
    """Grid for toppra: half the nodes uniform in σ, half where the joint path bends most
    (‖q''(σ)/a_max‖∞), so blends and the neighbourhood of singularities are resolved."""
    length = jp.length_m
    fine = np.linspace(0.0, length, 20 * intervals + 1)
    bend = np.max(np.abs(jp(fine, 2)) / a_max, axis=1)
    rho = 0.5 / length + 0.5 * bend / max(np.trapezoid(bend, fine), 1e-300)
    cum = np.concatenate([[0.0], np.cumsum((rho[1:] + rho[:-1]) / 2 * np.diff(fine))])
    grid = np.interp(np.linspace(0.0, cum[-1], intervals + 1), cum, fine)
    grid[0], grid[-1] = 0.0, length
    return grid


def jerk_step(
    pd: PathDynamics, node: int, qs: np.ndarray, accel: float, rate_max: np.ndarray | None, eps: float
) -> float:
    """Length (m) of the constant-jerk interval at a path end (`node` 0 or −1) that ramps |σ̈| from 0 to
    `accel` in the shortest time t the torque-rate limit allows. In the ramp the inertial rate m·j
    (j = a/t) is constant and every moving joint's Coulomb term crosses its band |q̇| ≲ 2ε, adding up
    to ±0.56·Fc·√(2|q'|·j/ε) — with the inertial rate when starting, against it when stopping (see
    `path_nlp`). σ at the end of the ramp is a·t²/6; the ramp lasts long enough to reach σ̇ = S_MIN."""
    if rate_max is None or accel <= 0:
        return 0.0
    fc = coulomb_levels(pd)
    sign_f = np.sign(qs) * (1.0 if node == 0 else -1.0) * np.sign(pd.m[node])
    t = np.geomspace(1e-5, 1.0, 400)[:, None]
    inertial = np.abs(pd.m[node]) * accel / t
    band = 0.56 * fc * np.sqrt(2 * np.abs(qs) * accel / (t * eps))
    worst = np.maximum(inertial, np.abs(inertial + sign_f * band)) / rate_max
    ok = np.all(worst <= 1.0, axis=1)
    t_min = float(t[np.argmax(ok), 0]) if ok.any() else 1.0
    # The ramp must also reach the NLP's speed floor (σ̇ ≥ S_MIN inside): b₁ = 1.5·σ̈₁·Δσ₀, and a slow
    # warm start's small end acceleration otherwise gives a step whose b₁ cannot reach S_MIN² within
    # the acceleration limits (IPOPT: Infeasible_Problem_Detected; the Unitree Z1's line at 4 × its
    # time-optimal duration). At the warm's acceleration the ramp ends on the floor; a longer one, to
    # 2·S_MIN, left the RX130L large circle at 8 × T_opt 1.010 × its torque-rate limit (measured).
    t_min = max(t_min, 2 * S_MIN / accel)
    return accel * t_min**2 / 6


def nlp_grid(
    jp: JointPath,
    warm: PathProfile,
    intervals: int,
    focus: list[tuple[float, float]] | None = None,
    first_step_m: float = 0.0,
    last_step_m: float = 0.0,
) -> np.ndarray:
    """Grid for the NLP. Node density: half uniform in σ, half in the warm start's time, four times
    that on the `focus` stretches (σ ranges, each widened by one regular spacing) — where the binding
    limit switches, which a continuous σ̈ can only follow as fast as the grid allows. At both ends the
    steps double from `first_step_m` / `last_step_m` (the constant-jerk ramp from rest, `jerk_step`)
    up to the regular spacing. The interior node nearest each joint reversal is moved onto it."""
    length = jp.length_m
    fine = np.linspace(0.0, length, 20 * intervals + 1)
    t_fine = np.interp(fine, warm.sigma, warm.t_nodes)
    rho = 0.5 / length + 0.5 * np.gradient(t_fine, fine) / warm.duration_s
    if focus:
        width = length / intervals
        base = rho.copy()
        for a, b in focus:
            rho = rho + 3 * base * ((fine > a - width) & (fine < b + width))
    cum = np.concatenate([[0.0], np.cumsum((rho[1:] + rho[:-1]) / 2 * np.diff(fine))])

    def ramp(first: float, h: float) -> list[float]:
        steps, s = [], max(first, 1e-6 * length, h / 256)
        while s < h / 1.5 and len(steps) < 10:
            steps.append(s)
            s *= 2
        return steps

    h0 = cum[-1] / intervals / rho[0]
    h1 = cum[-1] / intervals / rho[-1]
    head, tail = ramp(first_step_m, h0), ramp(last_step_m, h1)
    z0, z1 = sum(head), length - sum(tail)
    n_mid = intervals - len(head) - len(tail)
    c0, c1 = np.interp([z0, z1], fine, cum)
    mid = np.interp(np.linspace(c0, c1, n_mid + 1), cum, fine)
    grid = np.concatenate([np.cumsum([0.0, *head])[:-1], mid, (length - np.cumsum([0.0, *tail]))[::-1][1:]])
    grid[0], grid[-1] = 0.0, length
    lo, hi = len(head) + 1, intervals - len(tail) - 1
    for sr in reversal_points(jp):
        i = int(np.argmin(np.abs(grid - sr)))
        if lo <= i <= hi and grid[i - 1] + 1e-6 < sr < grid[i + 1] - 1e-6:
            grid[i] = sr
    return grid
