"""plan-ptp rows: the N = 100 OCP solve beside the paper's forward-dynamics multiple shooting of the same
problem (timed in the same run, under a wall-time cap), and the PtP duration beside plan-cp's."""

from __future__ import annotations

import shutil
import statistics
import time

from bench.table import Row
from rxcomm.model.robot import load_robot
from rxcomm.planning.cp import CpSettings, plan_cp
from rxcomm.planning.paths import load_path
from rxcomm.planning.ptp import plan_ptp
from rxcomm.planning.ptp_ocp import PtpOcp
from rxcomm.planning.ptp_problem import PtpDynamics, PtpLimits, PtpOptions
from rxcomm.planning.ptp_shooting import ShootingOcp
from rxcomm.planning.timing import PlanDynamics

LINE = "samples/rx130l/paths/line-near-singularity.yaml"


def bench_plan_ptp(quick: bool = False, shooting_cap_s: float | None = None) -> list[Row]:
    """One N = 100 solve (median over repeats; build and solve timed apart), L-BFGS and the
    forward-dynamics multiple shooting on the same end points, and PtP vs CP on the paper's line."""
    robot = load_robot("samples/rx130l")
    _, path = load_path(LINE, robot)
    cp_settings = CpSettings()
    cp = plan_cp(robot, path, PlanDynamics.load(robot, None, cp_settings.coulomb_eps_rad_s), cp_settings)
    q0, q1 = cp.q[0], cp.q[-1]
    dyn = PtpDynamics.from_parameters(robot)
    limits = PtpLimits.from_robot(robot)
    repeats = 1 if quick else 3

    def timed(options: PtpOptions) -> tuple[float, float, float, object]:
        """Medians of the build (wall), the solve (wall) and the whole plan_ptp call (process CPU:
        on a shared, loaded machine the wall time is 2-3× the compute)."""
        builds, solves, cpus, res = [], [], [], None
        PtpOcp(dyn, limits, options)  # a compile (cached on disk) is not part of a repeat
        for _ in range(repeats):
            t0 = time.perf_counter()
            ocp = PtpOcp(dyn, limits, options)
            builds.append(time.perf_counter() - t0)
            c0 = time.process_time()
            res = plan_ptp(robot, dyn, q0, q1, options, ocp=ocp)
            cpus.append(time.process_time() - c0)
            solves.append(res.solution.solve_seconds)
        return statistics.median(builds), statistics.median(solves), statistics.median(cpus), res

    # the default (node functions compiled unoptimised when a C compiler exists) against the virtual
    # machine, the default before issue 32, timed in the same run
    build100, solve100, cpu100, res100 = timed(PtpOptions(n_intervals=100))
    _, solve_vm, cpu_vm, res_vm = timed(PtpOptions(n_intervals=100, compile=False))
    _, solve50, _, res50 = timed(PtpOptions(n_intervals=50))
    _, solve_lbfgs, _, res_lbfgs = timed(PtpOptions(n_intervals=100, hessian="limited-memory"))
    compiled = None
    if shutil.which("gcc") or shutil.which("cc"):
        compiled = timed(PtpOptions(n_intervals=100, compile=True))
    cc = "cc -O0" if compiled is not None else "no C compiler: virtual machine"
    cap = shooting_cap_s or (30.0 if quick else 180.0)
    n_shoot = 20 if quick else 100
    shoot = ShootingOcp(dyn, limits, PtpOptions(n_intervals=n_shoot, max_wall_s=cap))
    sol = shoot.solve(q0, q1, res100.warm_start)
    shoot_label = (
        f"FD multiple shooting N={n_shoot}, RK4 ({sol.status}, {sol.iterations} it, "
        f"T = {sol.duration_s:.3f} s, cap {cap:.0f} s)"
    )
    vm = f"before: virtual machine ({res_vm.solution.iterations} it, T = {res_vm.duration_s:.4f} s)"
    default = (
        f"OCP solve N=100, default ({cc}; {res100.solution.iterations} it, T = {res100.duration_s:.4f} s)"
    )
    return [
        Row("plan-ptp", default, "s", solve100, paper="≈ 3 min (MUSCOD-II)", peer_name=vm, peer=solve_vm,
            target="≤ 0.5 s without a C compiler, ≤ 0.25 s with"),
        Row("plan-ptp", default + ", CPU of plan_ptp", "s", cpu100, peer_name=vm, peer=cpu_vm,
            target="≤ 0.25 s with a C compiler"),
        Row("plan-ptp", "OCP solve N=100 vs the paper's FD multiple shooting", "s", solve100,
            peer_name=shoot_label, peer=sol.solve_seconds + shoot.build_seconds, target="≤ 3 s"),
        Row("plan-ptp", "NLP build N=100 (window derivatives, compiled from the cache)", "s", build100),
        Row("plan-ptp", f"OCP solve N=100 vs L-BFGS ({res_lbfgs.solution.iterations} it)", "s", solve100,
            peer_name="same NLP, IPOPT L-BFGS", peer=solve_lbfgs),
        Row("plan-ptp", f"OCP solve N=50 ({res50.solution.iterations} it)", "s", solve50),
        *(
            []
            if compiled is None
            else [
                Row("plan-ptp", "OCP solve N=100, node functions optimised (--compile, cc -O1)", "s",
                    compiled[1], peer_name="default (cc -O0)", peer=solve100),
                Row("plan-ptp", "OCP solve N=100, --compile, CPU of plan_ptp", "s", compiled[2],
                    peer_name="default (cc -O0)", peer=cpu100),
            ]
        ),
        Row(
            "plan-ptp",
            "PtP duration, end points of the line near the wrist singularity",
            "s",
            res100.duration_s,
            paper="0.67 s vs CP 1.04 s (0.64)",
            peer_name="plan-cp on the line (same run)",
            peer=cp.duration_s,
            target="≤ 0.7 × CP",
        ),
        Row(
            "plan-ptp",
            "max limit ratio, dense at 400 µs",
            "",
            res100.max_limit_ratio,
            peer_name="virtual machine (before)",
            peer=res_vm.max_limit_ratio,
            target="≤ 1.01",
        ),
        Row("plan-ptp", "FD multiple shooting: max defect", "", sol.max_defect),
    ]  # fmt: skip


def rows(quick: bool) -> list[Row]:
    return bench_plan_ptp(quick)
