"""Levenberg–Marquardt fit of the weighted residual and its covariance, and the fitter that applies
one model (parameters, base, noise) to pose subsets: outlier removal, noise from the residuals
(variance components), k-fold cross-validation, the baseline-pose comparison.

`scipy.optimize.least_squares` (`lm`; `trf` with a robust loss) with the analytic Jacobian,
standard deviations from s²·(JᵀJ)⁻¹ with s² the residual variance per degree of freedom.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin
import scipy.linalg
import scipy.optimize
import scipy.stats

from rxcomm.calibration.compliance import TAU_REF_NM
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.priors import Regularised, prior_sigmas
from rxcomm.calibration.residuals import Problem
from rxcomm.calibration.settings import CalibrateSettings
from rxcomm.errors import InfeasibleError, InputError
from rxcomm.model.geometric_errors import (
    ErrorModel,
    IdentifiableSet,
    identification_jacobians,
    measurement_scaling,
    parameter_names,
)
from rxcomm.model.robot import Robot

# The range the data may give the geometric priors (× the manufacturing classes' σ): down to all but
# frames-only for an arm better than its class (architecture §11), up to a catalogue model's errors.
PRIOR_SCALE_MIN = 0.01
PRIOR_SCALE_MAX = 30.0

# The robust losses' scale on the weighted residual (3σ: a residual within the noise keeps most weight).
ROBUST_SCALE = 3.0

# The standard normal's 80 % quantile: a minimal detectable blunder is flagged 4 times in 5.
DETECTION_POWER_Z = 0.8416


def loss_weights(loss: str, u: np.ndarray) -> np.ndarray:
    """The weights ρ'(u²) a fit with `loss` gives the weighted residuals u·ROBUST_SCALE at its
    solution (`scipy.optimize.least_squares`' losses; 1 for linear): there Jᵀ·W·r = 0."""
    z = u * u
    if loss == "linear":
        return np.ones_like(z)
    if loss == "cauchy":
        return 1.0 / (1.0 + z)
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1.0)))
    raise ValueError(f"unknown loss {loss!r}")


@dataclass(frozen=True)
class FitResult:
    errors: ErrorModel
    std: np.ndarray  # [48], NaN for fixed parameters
    estimated: np.ndarray  # [48] bool
    residual_scale: float  # sqrt(χ²/dof) of the weighted residuals
    iterations: int
    cond: float  # of the scaled Jacobian at the solution
    compliance: np.ndarray | None = None  # [n] rad/(N·m), 0 for rigid joints; None: rigid model
    compliance_std: np.ndarray | None = None  # [n], NaN for joints not fitted
    x: np.ndarray | None = None  # the solution vector (warm starts)

    def link_angles(self, q: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The links' angles of this model at encoder angles q under holding torques τ."""
        return q if self.compliance is None else q - tau * self.compliance


def at_links(ms: MeasurementSet, fit: FitResult, tau: np.ndarray) -> MeasurementSet:
    """`ms` with the joint angles the fit's model puts the links at (compliance deflection)."""
    return ms if fit.compliance is None else replace(ms, q=fit.link_angles(ms.q, tau))


def fit_problem(
    robot: Robot,
    ms: MeasurementSet,
    t2b: pin.SE3,
    idx: np.ndarray,
    sigma_p: float,
    sigma_o: float,
    point: np.ndarray | None,
    settings: CalibrateSettings,
    x0: np.ndarray | None = None,
    tau: np.ndarray | None = None,
    comp: tuple[int, ...] = (),
    prior: np.ndarray | None = None,
    prior_corr: np.ndarray | None = None,
) -> FitResult:
    """The (regularised) fit: `prior` [k] the prior σ of each element of the solution vector (inf:
    flat; None: no prior, plain least squares), `prior_corr` [k, k] their correlation (None: none);
    its rows join the weighted residual (`Regularised`, `priors`)."""
    idx = np.asarray(idx, dtype=int)
    prob = Problem(robot, ms.q, ms.position_m, ms.rotation, t2b, sigma_p, sigma_o, idx, point, tau, comp)
    aug = Regularised(prob, prior, prior_corr)
    k = len(idx) + len(comp)
    x0 = np.zeros(k) if x0 is None else np.asarray(x0, dtype=float)
    m = prob.residual(x0).size
    if m <= aug.n_free:
        raise InputError(f"{m} equations for {aug.n_free} parameters: too few poses", file=ms.source)
    if settings.loss == "linear":
        sol = scipy.optimize.least_squares(
            aug.residual, x0, jac=aug.jacobian, method="lm", max_nfev=settings.max_iterations * (k + 1)
        )
    else:
        sol = scipy.optimize.least_squares(
            aug.residual,
            x0,
            jac=aug.jacobian,
            method="trf",
            loss=settings.loss,
            f_scale=ROBUST_SCALE,
            max_nfev=settings.max_iterations,
        )
    if not sol.success:
        raise InfeasibleError(f"calibration did not converge: {sol.message}")
    jac = prob.jacobian(sol.x)
    res = prob.residual(sol.x)
    info = jac.T @ jac + aug.information
    # the parameters the data spend (the hat matrix's trace; k without a prior)
    dof = max(m - float(np.trace(np.linalg.pinv(info) @ (jac.T @ jac))), 1.0)
    s2 = float(res @ res) / dof
    sv = np.linalg.svd(jac * (1 / np.linalg.norm(jac, axis=0)), compute_uv=False)
    cov = s2 * np.linalg.pinv(info)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    names = parameter_names(robot)
    std = np.full(len(names), np.nan)
    std[idx] = sd[: len(idx)]
    est = np.zeros(len(names), dtype=bool)
    est[idx] = True
    compliance = compliance_std = None
    if comp:
        compliance, compliance_std = np.zeros(robot.n), np.full(robot.n, np.nan)
        compliance[list(comp)] = sol.x[len(idx) :] / TAU_REF_NM
        compliance_std[list(comp)] = sd[len(idx) :] / TAU_REF_NM
    return FitResult(
        prob.errors(sol.x),
        std,
        est,
        math.sqrt(s2),
        int(sol.nfev),
        float(sv[0] / sv[-1]),
        compliance,
        compliance_std,
        np.array(sol.x),
    )


def rank_check(robot: Robot, ms: MeasurementSet, ident: IdentifiableSet, point: np.ndarray | None) -> None:
    """Refuse a fit pose set that cannot identify the structurally identifiable parameters."""
    po = ms.position_only
    jac = identification_jacobians(robot, ms.q, None, None, po, point)
    row_w, col_s = measurement_scaling(robot, po)
    idx = list(ident.indices)
    a = (jac * row_w[None, :, None]).reshape(-1, len(parameter_names(robot)))[:, idx] * col_s[idx]
    a = a / np.maximum(np.linalg.norm(a, axis=0), 1e-300)
    _, r, piv = scipy.linalg.qr(a, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    weak = piv[diag < 1e-8 * diag[0]] if diag.size else []
    if len(weak):
        names = [ident.names[i] for i in weak]
        raise InputError(
            f"the {ms.n} fit poses cannot identify {len(names)} of the {len(idx)} identifiable parameters "
            f"(rank-deficient pose set; e.g. {names[:6]}): measure more varied poses (rxcomm select-configs)",
            file=ms.source,
            field="poses",
        )


@dataclass(frozen=True)
class BaselineComparison:
    """The full calibration fitted to the `baseline` poses instead (a reference set such as
    select-configs' linear scan), judged on the same held-out measurements as the main fit.

    `worse_p_value`: one-sided Wilcoxon signed-rank test that the baseline fit misses the held-out
    poses by more than the main fit, pose by pose, in the fit's own metric (the weighted residual:
    position /σ_p, orientation /σ_o); small means measurably worse. `fit` is None when the baseline
    poses cannot identify the parameters; `note` then says why."""

    n_poses: int
    fit: FitResult | None
    fit_idx: np.ndarray
    outlier_idx: np.ndarray
    worse_p_value: float | None
    note: str | None = None


@dataclass(frozen=True)
class Fitter:
    """One weighted fit setting (model, base, noise, parameters) applied to pose subsets."""

    robot: Robot
    ms: MeasurementSet
    t2b: pin.SE3
    idx: np.ndarray  # geometric parameters (into the 48)
    sigma_p: float
    sigma_o: float
    point: np.ndarray | None
    settings: CalibrateSettings
    need: int  # the fewest poses the parameters need
    tau: np.ndarray  # [N, n] prior holding torques of all poses of `ms`
    comp: tuple[int, ...] = ()  # compliant joints
    x0: np.ndarray | None = None
    geometric_prior: np.ndarray | None = None  # [48] prior σ (`priors.effective_priors`)
    geometric_corr: np.ndarray | None = None  # [48, 48] their correlation (the same)
    prior_scale: float = 1.0  # on the geometric priors' σ, as the data ask (`noise_from_residuals`)

    def problem(self, poses: np.ndarray) -> Problem:
        sub = self.ms.subset(poses)
        return Problem(
            self.robot,
            sub.q,
            sub.position_m,
            sub.rotation,
            self.t2b,
            self.sigma_p,
            self.sigma_o,
            np.asarray(self.idx),
            self.point,
            self.tau[poses],
            self.comp,
        )

    @property
    def prior(self) -> np.ndarray | None:
        """Prior σ of the solution vector (`priors`), None when the fit is not regularised."""
        if not self.settings.regularise:
            return None
        out = prior_sigmas(self.robot, self.idx, self.comp, self.geometric_prior)
        out[: len(self.idx)] *= self.prior_scale
        return out

    @property
    def prior_corr(self) -> np.ndarray | None:
        """[k, k] the prior's correlation over the solution vector (the compliances uncorrelated)."""
        if self.geometric_corr is None or not self.settings.regularise:
            return None
        k = len(self.idx) + len(self.comp)
        out = np.eye(k)
        idx = np.asarray(self.idx, dtype=int)
        out[: idx.size, : idx.size] = self.geometric_corr[np.ix_(idx, idx)]
        return out

    def fit(self, poses: np.ndarray, x0: np.ndarray | None = None) -> FitResult:
        return fit_problem(
            self.robot,
            self.ms.subset(poses),
            self.t2b,
            self.idx,
            self.sigma_p,
            self.sigma_o,
            self.point,
            self.settings,
            self.x0 if x0 is None else x0,
            self.tau[poses],
            self.comp,
            self.prior,
            self.prior_corr,
        )

    def residuals(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """[n, rows]: the weighted residuals (position /σ_p, orientation /σ_o) of `fit` at `poses`."""
        return self.problem(poses).residual(fit.x).reshape(poses.size, -1)

    def standardised(self, poses: np.ndarray, fit: FitResult) -> tuple[np.ndarray, np.ndarray]:
        """([n, rows] the weighted residuals r_k/√v_k, [n, rows] v_k): v_k the variance of r_k over
        the noise (unit-weight units) for the fit's weights W at its solution (its loss; the prior
        rows included), A = JᵀWJ: r = (I − J·A⁻¹·JᵀW)·ε, so v = diag((I − JA⁻¹JᵀW)(I − JA⁻¹JᵀW)ᵀ),
        which is 1 − h_k (h the regularised hat matrix's diagonal) for a plain fit, so a pose the fit
        leans on is not hidden by its leverage. A robust fit that gives a row little weight does not
        lean on it: its residual is a prediction error, v_k → 1 + J_k·A⁻¹·J_kᵀ, not 1 − h_k (which
        overstated such a pose by 1/√((1 − h)(1 + h')): 8.3σ for 2.3σ of noise on a clean
        24-pose camera-grade campaign, architecture §11)."""
        full, var, prior_rows = self._row_variances(poses, fit)
        n_data = full.size - prior_rows.size
        res, red = full[:n_data], np.maximum(var[:n_data], 1e-6)
        return (res / np.sqrt(red)).reshape(poses.size, -1), red.reshape(poses.size, -1)

    def detectable_blunders_m(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """[n, 3] per pose and position axis, the minimal detectable blunder (Baarda): the error in
        that one component which `fit_dropping_outliers` flags 4 times in 5, (outlier_sigma + 0.84)·
        σ_p/√v_k. A blunder b moves its standardised residual by b·√v_k/σ_p (`standardised`), so a
        component the fit leans on (v_k = 1 − h_k small: no other pose checks it) hides a large one."""
        _, var = self.standardised(poses, fit)
        return (self.settings.outlier_sigma + DETECTION_POWER_Z) * self.sigma_p / np.sqrt(var[:, :3])

    def _row_variances(self, poses: np.ndarray, fit: FitResult) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the weighted residual: the data rows, then the prior rows; each row's variance v_k
        (`standardised`); the parameter each prior row holds (`Regularised.rows`))."""
        aug = Regularised(self.problem(poses), self.prior, self.prior_corr)
        full = aug.residual(fit.x)  # the data rows, then the prior rows
        jac = aug.jacobian(fit.x)
        w = loss_weights(self.settings.loss, full / ROBUST_SCALE)
        sw = np.sqrt(w)
        qm, rm = np.linalg.qr(jac * sw[:, None])  # W^½·J = Q·R
        u = jac @ np.linalg.pinv(rm)  # J·R⁻¹, so J·A⁻¹·JᵀW = u·vᵀ
        v = qm * sw[:, None]
        var = 1.0 - 2.0 * np.sum(u * v, axis=1) + np.einsum("ij,jk,ik->i", u, v.T @ v, u)
        return full, var, aug.rows

    def robust(self) -> Fitter:
        """This fitter with a redescending loss (Cauchy, scale 3σ) unless a robust loss is set: the
        fit then does not lean toward a blunder, so the blunder stays in its own residual."""
        if self.settings.loss != "linear":
            return self
        return replace(self, settings=self.settings.model_copy(update={"loss": "cauchy"}))

    def fit_dropping_outliers(self, poses: np.ndarray) -> tuple[FitResult, np.ndarray, np.ndarray]:
        """(fit, the poses it used, the flagged poses). Each pose is tested on a robust fit
        (`robust`): a pose with a standardised residual component (`standardised`: r_k/√v_k, v_k
        its variance under the robust fit's weights) beyond outlier_sigma σ is flagged, σ the
        fitter's noise (≥ the MAD of its quantity's components, when the noise is underestimated:
        `_robust_scales`). One blunder smears into its neighbours' residuals through the fit, so when
        dropping, the worst pose only is removed and the rest refitted, until none is beyond (at most
        a quarter of the poses); the fit returned is this fitter's on the rest."""
        rob = self.robust()
        result = rob.fit(poses)
        flagged: list[int] = []
        while True:
            z, _ = rob.standardised(poses, result)
            worst = np.max(np.abs(z) / _robust_scales(z), axis=1)
            beyond = worst > self.settings.outlier_sigma
            if not np.any(beyond):
                break
            if not self.settings.drop_outliers:
                flagged += poses[beyond].tolist()
                break
            k = int(np.argmax(worst))
            flagged.append(int(poses[k]))
            poses = np.delete(poses, k)
            if poses.size < self.need or len(flagged) > max(1, poses.size // 4):
                raise InputError(
                    f"{len(flagged)} outlier poses ({flagged[:10]}) leave {poses.size} fit poses: the "
                    f"measurements do not fit the model (need {self.need} good poses)",
                    file=self.ms.source,
                    field="poses",
                )
            result = rob.fit(poses, result.x)
        result = result if rob is self else self.fit(poses, result.x)
        return result, poses, np.array(sorted(flagged), dtype=int)

    def noise_from_residuals(
        self, poses: np.ndarray, robust: bool, rounds: int = 6, noise: bool = True
    ) -> Fitter:
        """This fitter with σ_p, σ_o estimated from the fit's residuals and its priors' scale
        (variance components, `variance_factors`), refitted until the weights settle. `robust`: from
        a robust fit (`robust`), whose median scale a blunder does not inflate; `noise` False: σ_p,
        σ_o stay (given), only the priors' scale is estimated."""
        f = self.robust() if robust else self
        fit = None
        for _ in range(rounds):
            fit = f.fit(poses, None if fit is None else fit.x)
            k_p, k_o, k_prior = f.variance_factors(poses, fit, robust, noise)
            scale = min(max(f.prior_scale * k_prior, PRIOR_SCALE_MIN), PRIOR_SCALE_MAX)
            settled = abs(scale / f.prior_scale - 1) < 0.01
            f = replace(f, sigma_p=f.sigma_p * k_p, sigma_o=f.sigma_o * k_o, prior_scale=scale)
            if abs(k_p - 1) < 0.01 and abs(k_o - 1) < 0.01 and settled:
                break
        return replace(f, settings=self.settings)

    def variance_factors(
        self, poses: np.ndarray, fit: FitResult, robust: bool, noise: bool = True
    ) -> tuple[float, float, float]:
        """(k_p, k_o, k_prior): the factors the residuals ask of σ_p, σ_o and the geometric priors'
        σ. Per group s² = Σ r_k² / Σ v_k (Förstner; v_k the row's variance, `standardised`: 1 − h_k
        for a plain fit), so the redundancy the fit leaves each row is accounted for; `robust`: the
        noise from the scale 1.4826·median|r_k/√v_k| instead, which a blunder does not inflate. The
        geometric priors are a group of their own (Koch & Kusche 2002, regularisation parameters as
        variance components): their rows x_k/σ_k say how far the joint errors are from the
        manufacturing classes, so a robot further off its nominal model than the classes is not held
        to them, and one better than them is not given their freedom to fit noise (architecture §11).
        1 where a group is not estimated (`noise` False; no prior, or one the data leave less than
        half a row of say)."""
        full, var, prior_rows = self._row_variances(poses, fit)
        n_data = full.size - prior_rows.size
        k_p = k_o = k_prior = 1.0
        if noise:
            red = np.maximum(var[:n_data], 1e-6).reshape(poses.size, -1)
            z = full[:n_data].reshape(poses.size, -1) / np.sqrt(red)  # as `standardised`
            k = []
            for c in (slice(0, 3), slice(3, 6))[: z.shape[1] // 3]:
                if robust:
                    k.append(1.4826 * float(np.median(np.abs(z[:, c]))))
                else:
                    k.append(math.sqrt(float(np.sum(z[:, c] ** 2 * red[:, c]) / np.sum(red[:, c]))))
            k_p, k_o = k[0], (k[1] if len(k) == 2 else 1.0)
        if self.prior is not None:
            geo = n_data + np.flatnonzero(prior_rows < len(self.idx))
            if geo.size and float(np.sum(var[geo])) > 0.5:
                k_prior = math.sqrt(float(np.sum(full[geo] ** 2) / np.sum(var[geo])))
        return k_p, k_o, k_prior

    def compare_baseline(self, poses: np.ndarray, heldout: np.ndarray, main: FitResult) -> BaselineComparison:
        """The same calibration from the baseline poses; a set that cannot identify the parameters
        is reported, not raised (it is a reference, not the user's calibration)."""
        none = np.array([], dtype=int)
        try:
            if poses.size < self.need:
                raise InputError(f"{poses.size} valid poses, the parameters need at least {self.need}")
            names = parameter_names(self.robot)
            sub = IdentifiableSet(tuple(self.idx), tuple(names[i] for i in self.idx), (), 0, 0.0, 0.0, 0.0)
            rank_check(self.robot, self.ms.subset(poses), sub, self.point)
            fit, used, flagged = self.fit_dropping_outliers(poses)
        except InputError as e:
            return BaselineComparison(int(poses.size), None, none, none, None, note=e.reason)
        except InfeasibleError as e:
            return BaselineComparison(int(poses.size), None, none, none, None, note=str(e))
        p_value = None
        if heldout.size:
            diff = self.weighted_misfit(heldout, fit) - self.weighted_misfit(heldout, main)
            if np.any(diff != 0):
                p_value = float(scipy.stats.wilcoxon(diff, alternative="greater").pvalue)
        return BaselineComparison(int(poses.size), fit, used, flagged, p_value)

    def weighted_misfit(self, poses: np.ndarray, fit: FitResult) -> np.ndarray:
        """Per pose, ‖r‖² of the weighted residual as the fit weighs it, of `fit`'s parameters."""
        return np.sum(self.residuals(poses, fit) ** 2, axis=1)

    def cross_validate(self, poses: np.ndarray, full: FitResult, folds: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per pose of `poses`: (weighted misfit, position error² m², orientation error² rad²) when its
        fold was held out; each fold's fit starts from `full` (the fit of all poses)."""
        mis = np.empty(poses.size)
        e_p = np.empty(poses.size)
        e_o = np.full(poses.size, np.nan)
        for k in np.unique(folds):
            test, train = poses[folds == k], poses[folds != k]
            fit = self.fit(train, full.x)
            r = self.residuals(test, fit)
            sel = folds == k
            mis[sel] = np.sum(r**2, axis=1)
            e_p[sel] = np.sum((r[:, :3] * self.sigma_p) ** 2, axis=1)
            if r.shape[1] == 6:
                e_o[sel] = np.sum((r[:, 3:] * self.sigma_o) ** 2, axis=1)
        return mis, e_p, e_o


def _robust_scales(z: np.ndarray) -> np.ndarray:
    """[rows]: per measured quantity (the position columns, the orientation columns of `z` [n, rows]),
    1.4826 × the median |z|, at least 1: σ is raised where the noise is underestimated, each group
    on its own (pooled, orientation residuals 1.35× their σ raised a position blunder's threshold
    to 6.1σ, and the blunder, kept, inflated the position noise by 27 %, architecture §11)."""
    out = np.ones(z.shape[1])
    for cols in (slice(0, 3), slice(3, None)):
        part = np.abs(z[:, cols])
        if part.size:
            out[cols] = max(1.4826 * float(np.median(part)), 1.0)
    return out
