"""The excitation's design limits and their check on sampled trajectories (`identification.excitation`).

**Constraints** (paper eq. 30): joint position (minus a margin), velocity, acceleration (fractions of
the limits), motor torque |τ| ≤ fraction·peak from the prior (URDF + drives.yaml) model, and the
tool (TCP), wrist centre (joint 5 origin) and elbow (joint 3 origin) inside the cell's allowed-region
boxes. Position, velocity and acceleration are linear in x; torque and positions come with their
Jacobians from CasADi. Constraints imposed at a finite grid are violated between its points (by 1–2 %
at the paper's k = 80), so each solve is followed by a dense check (`check_samples` per period) and
the worst violating times are added to the constraint grid (an exchange method for the
semi-infinite problem) until the dense check holds; the result is verified again at the drive cycle
with Pinocchio, independently of the CasADi model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from rxcomm.errors import InputError
from rxcomm.identification.excitation_trajectory import fourier_basis, fourier_jerk_basis
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.dynamics import COULOMB_EPS_NLP_RAD_S, DynamicParameters
from rxcomm.model.limits import TorqueRateLimit
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import AllowedRegion, Box
from rxcomm.schemas.excitation import ExcitationSettings

REGION_POINTS = ("tool", "wrist_centre", "elbow")


def region_points(robot: Robot, q: np.ndarray) -> dict[str, np.ndarray]:
    """Tool (TCP), wrist centre and elbow (origins of `Robot.wrist_joint_id`, `elbow_joint_id`)
    positions [N, 3], base frame, by Pinocchio."""
    q = np.atleast_2d(q)
    model, data = robot.model, robot.create_data()
    out = {k: np.empty((len(q), 3)) for k in REGION_POINTS}
    for i, qi in enumerate(q):
        pin.forwardKinematics(model, data, qi)
        out["tool"][i] = pin.updateFramePlacement(model, data, robot.tcp_frame_id).translation
        out["wrist_centre"][i] = data.oMi[robot.wrist_joint_id].translation
        out["elbow"][i] = data.oMi[robot.elbow_joint_id].translation
    return out


def box_centre_half(box: Box, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.array(box.min_m), np.array(box.max_m)
    half = (hi - lo) / 2 - margin
    if np.any(half <= 0):
        raise InputError(f"the allowed-region margin {margin} m leaves an empty box", field="allowed_region")
    return (hi + lo) / 2, half


# ------------------------------------------------------------------------------------------------
# Design limits


@dataclass(frozen=True, eq=False)
class DesignLimits:
    """The design limits as centre ± half-width: joint position (minus the margin), velocity,
    acceleration and torque (fractions of the robot's limits), the region boxes (minus their margin)
    stacked tool, wrist centre, elbow; `qdd_cross_max`, the |q̈| allowed where q̇_j = 0 (Fc·q̈/ε
    within the torque-rate budget, `ExcitationProblem.crossings`; inf without friction)."""

    q_centre: np.ndarray
    q_half: np.ndarray
    v_half: np.ndarray
    a_half: np.ndarray
    tau_half: np.ndarray
    qdd_cross_max: np.ndarray
    box_centre: np.ndarray
    box_half: np.ndarray
    has_region: bool

    @classmethod
    def from_settings(
        cls, robot: Robot, region: AllowedRegion | None, s: ExcitationSettings, prior: DynamicParameters
    ) -> DesignLimits:
        q_lo, q_hi = robot.q_min + s.position_margin_rad, robot.q_max - s.position_margin_rad
        if np.any(q_hi <= q_lo):
            raise InputError("position_margin_rad leaves no joint range", field="position_margin_rad")
        fc = prior.coulomb_nm
        with np.errstate(divide="ignore"):
            qdd_cross_max = np.where(
                fc > 0,
                (1.0 - s.torque_rate_reserve)
                * robot.tau_rate_max
                * COULOMB_EPS_NLP_RAD_S
                / np.maximum(fc, 1e-300),
                np.inf,
            )
        if region is not None:
            boxes = [box_centre_half(getattr(region, k), s.region_margin_m) for k in REGION_POINTS]
            box_centre = np.concatenate([c for c, _ in boxes])
            box_half = np.concatenate([h for _, h in boxes])
        else:
            box_centre, box_half = np.zeros(0), np.zeros(0)
        return cls(
            q_centre=(q_hi + q_lo) / 2,
            q_half=(q_hi - q_lo) / 2,
            v_half=s.velocity_fraction * robot.v_max,
            a_half=s.acceleration_fraction * robot.a_max,
            tau_half=s.torque_fraction * robot.tau_max,
            qdd_cross_max=qdd_cross_max,
            box_centre=box_centre,
            box_half=box_half,
            has_region=region is not None,
        )

    @property
    def nl_centre(self) -> np.ndarray:
        """Centres of the nonlinear limits: the torques (0), then the region coordinates."""
        return np.concatenate([np.zeros(len(self.tau_half)), self.box_centre])

    @property
    def nl_half(self) -> np.ndarray:
        return np.concatenate([self.tau_half, self.box_half])

    def ratios(self, robot: Robot, samples: Trajectory) -> np.ndarray:
        """|value − centre|/half of the design limits on the samples (Pinocchio), max per sample."""
        per = [
            np.abs(samples.q - self.q_centre) / self.q_half,
            np.abs(samples.qd) / self.v_half,
            np.abs(samples.qdd) / self.a_half,
            np.abs(samples.tau_ff) / self.tau_half,
            TorqueRateLimit(robot.tau_rate_max).ratios(
                samples.t, samples.q, samples.qd, samples.qdd, samples.tau_ff
            ),
        ]
        if self.has_region:
            pts = region_points(robot, samples.q)
            c = self.box_centre.reshape(3, 3)
            h = self.box_half.reshape(3, 3)
            per += [np.abs(pts[name] - c[i]) / h[i] for i, name in enumerate(REGION_POINTS)]
        return np.max(np.concatenate(per, axis=1), axis=1)


def robot_limit_ratios(
    robot: Robot, region: AllowedRegion | None, samples: Trajectory
) -> tuple[dict[str, float], tuple[str, str, float, float]]:
    """Max value/limit per limit over the samples against the robot's limits (position, velocity,
    acceleration, torque, torque rate) and the allowed-region boxes (without margin), and the worst
    (limit, joint or axis, t, ratio)."""
    centre, half = (robot.q_max + robot.q_min) / 2, (robot.q_max - robot.q_min) / 2
    per = {
        "position": np.abs(samples.q - centre) / half,
        "velocity": np.abs(samples.qd) / robot.v_max,
        "acceleration": np.abs(samples.qdd) / robot.a_max,
        "torque": np.abs(samples.tau_ff) / robot.tau_max,
        "torque_rate": TorqueRateLimit(robot.tau_rate_max).ratios(
            samples.t, samples.q, samples.qd, samples.qdd, samples.tau_ff
        ),
    }
    labels = {k: list(robot.joint_names) for k in per}
    if region is not None:
        pts = region_points(robot, samples.q)
        for name in REGION_POINTS:
            c, h = box_centre_half(getattr(region, name), 0.0)
            per[f"region_{name}"] = np.abs(pts[name] - c) / h
            labels[f"region_{name}"] = ["x", "y", "z"]
    worst_key = max(per, key=lambda k: per[k].max())
    i, j = np.unravel_index(np.argmax(per[worst_key]), per[worst_key].shape)
    worst = (worst_key, labels[worst_key][j], float(samples.t[i]), float(per[worst_key][i, j]))
    return {k: float(v.max()) for k, v in per.items()}, worst


def reversal_ratios(
    xf: np.ndarray,
    t: np.ndarray,
    omega: float,
    harmonics: int,
    qdd_cross_max: np.ndarray,
    bv: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The torque-rate limit where a joint's velocity changes sign, for the Fourier variables xf
    [n, 2N − 1] with reversals found on the grid t: (ratios [n, 2N], ∂ratio/∂xf [n, 2N, n, 2N − 1]);
    unused slots are 0 with zero gradient.

    `run` computes τ_ff with Coulomb friction smoothed to Fc·tanh(q̇/ε), whose rate through q̇ = 0
    is Fc·q̈/ε: a narrow spike (≈ 2ε/q̈, a few ms) that a check grid misses, so it is constrained
    where it happens. q̇_j, a trigonometric polynomial of degree N, has at most 2N zeros per
    period, found by sign changes on the check grid and refined by Newton steps; the ratio is
    |q̈_j(t*)|·Fc_j/ε / (budget·rate_max_j), its gradient ∂q̈/∂x + q⃛·∂t*/∂x with
    ∂t*/∂x = −(∂q̇/∂x)/q̈ (implicit function). `bv`, the velocity basis on t, when the caller has
    it cached (the NLP calls this every iteration on the same grid)."""

    n, m, k = xf.shape[0], xf.shape[1], 2 * harmonics
    if bv is None:
        _, bv, _ = fourier_basis(t, omega, harmonics)
    v = bv @ xf.T  # [len(t), n]
    ratios = np.zeros((n, k))
    jac = np.zeros((n, k, n, m))
    dt = t[1] - t[0]
    # Every joint's reversals in one array (the bases on one call, not one per joint and step).
    joints, guesses = [], []
    for j in np.flatnonzero(qdd_cross_max < np.inf):
        vj = v[:, j]
        nxt = np.roll(vj, -1)
        idx = np.flatnonzero(vj * nxt < 0)
        if len(idx):
            joints.append(j)
            guesses.append(t[idx] + dt * vj[idx] / (vj[idx] - nxt[idx]))
    if not joints:
        return ratios, jac
    ends = np.cumsum([len(g) for g in guesses])
    spans = [slice(e - len(g), e) for e, g in zip(ends, guesses, strict=True)]
    ts = np.concatenate(guesses)
    for _ in range(2):  # Newton on q̇_j(t) = 0
        _, bv_all, ba_all = fourier_basis(ts, omega, harmonics)
        ts = np.concatenate(
            [
                ts[sp] - (bv_all[sp] @ xf[j]) / (ba_all[sp] @ xf[j])
                for j, sp in zip(joints, spans, strict=True)
            ]
        )
    _, bv_all, ba_all = fourier_basis(ts, omega, harmonics)
    bj_all = fourier_jerk_basis(ts, omega, harmonics)
    for j, sp in zip(joints, spans, strict=True):
        bvs, bas = bv_all[sp], ba_all[sp]
        a, jerk = bas @ xf[j], bj_all[sp] @ xf[j]
        order = np.argsort(-np.abs(a))[:k]  # at most 2N; keep the largest if rounding found more
        a, jerk, bvs, bas = a[order], jerk[order], bvs[order], bas[order]
        sgn = np.sign(a) / qdd_cross_max[j]
        ratios[j, : len(a)] = r = np.abs(a) / qdd_cross_max[j]
        # A near-tangent reversal (q̈ → 0) has a tiny ratio but an unbounded ∂t*/∂x: far from
        # its limit, the row is left without gradient rather than upset SLSQP's subproblem.
        live = r > 0.25
        jac[j, : len(a), j, :] = (sgn * live)[:, None] * (
            bas - (jerk / np.where(live, a, 1.0))[:, None] * bvs
        )
    return ratios, jac
