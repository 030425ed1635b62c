"""What is wrong with measurements that do not fit the robot, and which held-out poses disagree.

`joint_mixup`: a measured set that the nominal robot fits far better with two joint columns swapped
or one joint's sign flipped is named as such (the exporter's joint order or sign convention), rather
than blamed on the angle convention or units. Each alternative is scored like the data themselves:
the closed-form base and tool frames (`frames.estimate_frames`), then the rms position left (plus the
rms orientation × the arm's characteristic length when orientations are measured).

`heldout_disagreement`: held-out poses whose residual is beyond `outlier_sigma` of its prediction
σ (the noise and the fit's own uncertainty at that pose, σ²·(1 + j·C·jᵀ)) are named in a warning:
a pose measured at another tool, a moved tracker, a typo.
"""

from __future__ import annotations

import itertools

import numpy as np

from rxcomm.calibration.frames import estimate_frames
from rxcomm.calibration.lm import FitResult, Fitter
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.priors import Regularised
from rxcomm.calibration.residuals import log3
from rxcomm.errors import InputError
from rxcomm.model.geometric_errors import characteristic_length_m, predict_poses
from rxcomm.model.robot import Robot

# An alternative joint order or sign must leave less than this share of the data's own misfit.
MIXUP_RATIO = 0.2


def frames_misfit(robot: Robot, ms: MeasurementSet, point: np.ndarray | None) -> float:
    """rms position (m) left by the closed-form frames, plus rms orientation × characteristic length."""
    try:
        data = estimate_frames(robot, ms, point)
    except InputError:
        return float("inf")
    tool_point = data.tool.translation if point is None else data.tool.act(np.asarray(point, dtype=float))
    p, r = predict_poses(robot, ms.q, None, data.tracker_to_base, tool_point)
    out = float(np.sqrt(np.mean(np.sum((p - ms.position_m) ** 2, axis=1))))
    if ms.rotation is not None:
        left = log3(ms.rotation @ (r @ data.tool.rotation).transpose(0, 2, 1))
        out += float(np.sqrt(np.mean(np.sum(left**2, axis=1)))) * characteristic_length_m(robot)
    return out


def joint_mixup(robot: Robot, ms: MeasurementSet, point: np.ndarray | None) -> str | None:
    """The swapped joint pair or flipped joint sign that the data fit far better, said in a sentence;
    None when the data's own order and signs fit best (or nothing fits much better)."""
    own = frames_misfit(robot, ms, point)
    names = robot.joint_names
    alternatives = []
    for i, j in itertools.combinations(range(robot.n), 2):
        q = ms.q.copy()
        q[:, [i, j]] = q[:, [j, i]]
        alternatives.append((f"the columns of {names[i]} and {names[j]} are swapped", q))
    for j in range(robot.n):
        q = ms.q.copy()
        q[:, j] = -q[:, j]
        alternatives.append((f"{names[j]}'s sign is flipped", q))
    scored = []
    for what, q in alternatives:
        sub = MeasurementSet(q, ms.position_m, ms.rotation, ms.valid, ms.role, ms.source)
        scored.append((frames_misfit(robot, sub, point), what))
    best, what = min(scored)
    if not best < MIXUP_RATIO * own:
        return None
    return (
        f"the measurements fit the robot far better if {what} ({best * 1e3:.2f} vs {own * 1e3:.1f} mm "
        "left by the base and tool frames): check the joint order and sign convention of the export"
    )


def heldout_standardised(
    fitter: Fitter, result: FitResult, fit: np.ndarray, heldout: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(weighted residuals [n, k] of the held-out poses, the same over their prediction σ): the
    prediction's covariance from the fit poses `fit`, so a pose is scored against the noise plus
    the fit's own uncertainty there."""
    prob = fitter.problem(heldout)
    res = prob.residual(result.x).reshape(heldout.size, -1)
    jac = prob.jacobian(result.x)
    fit_prob = fitter.problem(fit)
    j_fit = fit_prob.jacobian(result.x)
    info = j_fit.T @ j_fit + Regularised(fit_prob, fitter.prior, fitter.prior_corr).information
    var = 1.0 + np.einsum("ij,jk,ik->i", jac, np.linalg.pinv(info), jac).reshape(heldout.size, -1)
    return res, res / np.sqrt(var)


def heldout_disagreement(
    fitter: Fitter, result: FitResult, fit: np.ndarray, heldout: np.ndarray
) -> tuple[np.ndarray, str | None]:
    """(the held-out poses beyond `outlier_sigma` prediction σ, a warning naming them or None); the
    prediction's covariance from the fit poses `fit`."""
    if heldout.size == 0:
        return heldout, None
    res, zs = heldout_standardised(fitter, result, fit, heldout)
    z = np.max(np.abs(zs), axis=1)
    bad = z > fitter.settings.outlier_sigma
    if not np.any(bad):
        return heldout[bad], None
    miss = np.linalg.norm(res[:, :3] * fitter.sigma_p, axis=1)
    poses = ", ".join(
        f"{int(i)} ({m * 1e3:.1f} mm, {s:.0f}σ)"
        for i, m, s in zip(heldout[bad], miss[bad], z[bad], strict=True)
    )
    return heldout[bad], (
        f"held-out poses disagree with the fit beyond the noise (> {fitter.settings.outlier_sigma:g}σ of "
        f"their prediction): {poses}; a moved tracker, another tool or a mistyped pose?"
    )
