"""Optimal exciting trajectories for dynamic identification (paper §4.2, architecture §7 excite).

The steps: `excitation_trajectory` (the Fourier parametrisation), `excitation_limits` (the design
limits and their check at the drive cycle), `excitation_problem` (the NLP: objective, constraints,
SLSQP); here the multi-start design.

**Starts.** SLSQP from several random *feasible* trajectories (random rest pose inside the region,
random coefficients scaled down by bisection until every limit holds densely); the best feasible
result wins. The same random feasible trajectories give the baseline figure the summary reports.

**Parallel starts.** The starts are independent (each seeded by its index) and SLSQP holds the GIL,
so they run in forked worker processes while the parent computes the baseline: one process per
start, up to twice the available cores. The starts' times differ up to 6× (RX130L, 4 starts: 0.7 to
4.1 s, the slow one an SLSQP run of 322 evaluations that ends outside a limit), so one process per
core would queue a short start behind the slow one; with a process each the OS shares the cores
and the wall time approaches the slowest start (measured 6.0 s against 6.6 s for one per core and
8.5 s serial, machine at load 1). On a loaded machine (load 3–7 on 2 cores) the workers get about
one core between them and the wall time is the serial one (15.3 against 15.7 s). A
child inherits the built problem (its compiled CasADi functions) through the fork and computes
exactly what the serial loop would: the result is identical, bit for bit, for the same seed
(tested). Where fork is unavailable, inside a daemonic process, or with one start, it is serial.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from rxcomm.errors import InfeasibleError
from rxcomm.identification.excitation_problem import ExcitationProblem, base_regressor, condition_numbers
from rxcomm.identification.excitation_trajectory import FourierTrajectory, sample_trajectory
from rxcomm.io.trajectory import Trajectory
from rxcomm.model.base_parameters import BaseParameterSet
from rxcomm.model.robot import Robot
from rxcomm.schemas.cell import AllowedRegion
from rxcomm.schemas.excitation import ExcitationSettings

Progress = Callable[[str, int, int], None]


@dataclass
class StartResult:
    seed: int
    initial_cond: float
    cond: float
    feasible: bool
    iterations: int
    seconds: float
    trajectory: FourierTrajectory | None = field(default=None, repr=False)


@dataclass(frozen=True, eq=False)
class ExcitationDesign:
    """What `design_excitation` returns. `cond`/`cond_raw` at the k objective samples (exact sign);
    `cond_dense` over the drive-cycle samples of one period; `baseline_cond` the median over random
    feasible trajectories of the same form; `limit_ratios` max value/robot limit on the drive-cycle
    samples (`max_limit_ratio` their max)."""

    trajectory: FourierTrajectory
    samples: Trajectory
    bset: BaseParameterSet
    cond: float
    cond_raw: float
    cond_dense: float
    baseline_cond: float
    baseline_conds: tuple[float, ...]
    starts: tuple[StartResult, ...]
    limit_ratios: dict[str, float]
    worst_limit: tuple[str, str, float, float]
    seconds: float

    @property
    def max_limit_ratio(self) -> float:
        return max(self.limit_ratios.values())


# ------------------------------------------------------------------------------------------------
# The starts

# The problem a forked worker inherits (set in the parent just before the pool forks).
_PROBLEM: ExcitationProblem | None = None


def _run_start(i: int, prob: ExcitationProblem | None = None) -> StartResult:
    """One seeded start: a random feasible trajectory, then SLSQP from it."""
    prob = prob or _PROBLEM
    assert prob is not None
    ts = time.perf_counter()
    x0 = prob.random_feasible(np.random.default_rng([prob.settings.seed, i]))
    c0 = prob.cond(x0)[0]
    x, iters, ok = prob.optimise(x0)
    return StartResult(
        seed=i,
        initial_cond=c0,
        cond=prob.cond(x)[0],
        feasible=ok,
        iterations=iters,
        seconds=time.perf_counter() - ts,
        trajectory=prob.trajectory(x),
    )


def available_workers() -> int:
    """Cores this process may run on (its affinity mask, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def _start_pool(prob: ExcitationProblem, workers: int) -> ProcessPoolExecutor | None:
    global _PROBLEM
    if (
        workers <= 1
        or "fork" not in multiprocessing.get_all_start_methods()
        or multiprocessing.current_process().daemon  # a daemonic process may not have children
    ):
        return None
    _PROBLEM = prob
    return ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"))


# ------------------------------------------------------------------------------------------------
# The design


def design_excitation(
    robot: Robot,
    region: AllowedRegion | None,
    settings: ExcitationSettings | None = None,
    *,
    bset: BaseParameterSet | None = None,
    progress: Progress | None = None,
    workers: int | None = None,
) -> ExcitationDesign:
    """Optimal exciting trajectory: the best of `settings.starts` seeded SLSQP runs, verified at the
    drive cycle, the starts on `workers` processes (default: one per start, up to twice the
    available cores; 1 = serial; the result is the same either way). Raises InfeasibleError when no
    start gives a trajectory within every limit."""
    t0 = time.perf_counter()
    settings = settings or ExcitationSettings()
    prob = ExcitationProblem(robot, region, settings, bset)
    n_workers = min(settings.starts, 2 * available_workers() if workers is None else workers)
    pool = _start_pool(prob, n_workers)
    try:
        futures: list[Future[StartResult]] = (
            [pool.submit(_run_start, i) for i in range(settings.starts)] if pool else []
        )
        n_base = settings.baseline_trajectories
        baseline = []
        for i in range(n_base):
            x = prob.random_feasible(np.random.default_rng([settings.seed, 1_000_003, i]))
            baseline.append(prob.cond(x)[0])
            if progress:
                progress("baseline", i + 1, n_base)
        starts: list[StartResult] = []
        for i in range(settings.starts):
            starts.append(futures[i].result() if pool else _run_start(i, prob))
            if progress:
                progress("starts", i + 1, settings.starts)
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)
    feasible = [s for s in starts if s.feasible]
    if not feasible:
        raise InfeasibleError(
            f"none of {len(starts)} excitation starts satisfied every limit on the dense check "
            f"(best cond {min(s.cond for s in starts):.3g}); try more starts or looser fractions"
        )
    best = min(feasible, key=lambda s: s.cond)
    traj = best.trajectory
    x = traj.free()[prob.free_mask]

    # Drive-cycle verification (Pinocchio, independent of the CasADi model): should a limit be
    # exceeded between the check grid's samples, tighten the NLP by the excess and re-solve.
    samples = sample_trajectory(robot, traj, 1, prob.prior)
    for _ in range(3):
        excess = float(prob.design_ratios(samples).max()) - 1.0
        if excess <= 0:
            break
        prob.tighten += 2 * excess
        x, _, _ = prob.optimise(x)
        traj = prob.trajectory(x)
        samples = sample_trajectory(robot, traj, 1, prob.prior)
    else:
        worst = prob.design_ratios(samples).max()
        raise InfeasibleError(f"the excitation exceeds a design limit at the drive cycle by {worst:.4f}")
    cond, cond_raw = prob.cond(x)
    w_dense = base_regressor(robot, prob.bset, samples.q, samples.qd, samples.qdd)
    cond_dense = condition_numbers(w_dense)[0]
    if settings.periods > 1:
        samples = sample_trajectory(robot, traj, settings.periods, prob.prior)
    ratios, worst = prob.limit_ratios(samples)
    return ExcitationDesign(
        trajectory=traj,
        samples=samples,
        bset=prob.bset,
        cond=cond,
        cond_raw=cond_raw,
        cond_dense=cond_dense,
        baseline_cond=float(np.median(baseline)),
        baseline_conds=tuple(baseline),
        starts=tuple(starts),
        limit_ratios=ratios,
        worst_limit=worst,
        seconds=time.perf_counter() - t0,
    )
