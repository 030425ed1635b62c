"""Two commissioning builds of the same robot side by side (issue 26): `python -m bench.plant_compare
build-ci build-ci-mujoco [--robot samples/rx130l]`. The same plans ran on each build's plant; this
prints what differs: joint lag and TCP error with and without feed-forward, torque RMS, held-out
calibration error and the 30 identifiable geometric parameters' z against the truth, the base
dynamic parameters' z against the truth's, validation R². Reads the builds' artefacts and the truth
(it scores recovery, as the tests do); writes nothing.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from rxcomm.calibration.lm import fit_problem
from rxcomm.calibration.loading import load_calibrated_robot
from rxcomm.calibration.measurements import MeasurementSet
from rxcomm.calibration.settings import CalibrateSettings
from rxcomm.cell.tracker import SimulatedTracker
from rxcomm.cell.truth import load_truth
from rxcomm.identification.kinematics import inertials_in_frames_of
from rxcomm.model.base_parameters import BaseParameterSet, base_parameters
from rxcomm.model.geometric_errors import ErrorModel, parameter_names, placement_to_se3, random_poses

RUNS = ("run-noff", "run-ff", "run-ptp", "run-factory-cp", "excite-log", "validation-log")


def _summary(build: Path, name: str) -> dict:
    return yaml.safe_load((build / f"{name}.yaml").read_text())["summary"]


def _torque_rms(build: Path, name: str) -> float | None:
    s = _summary(build, name)
    t = s.get("tau_squared_integral_nm2_s")
    return None if t is None else float(np.sqrt(t / s["duration_s"]))


def geometry_z(build: Path, truth_path: Path) -> tuple[float, float]:
    """(max |z| of the identifiable parameters against the truth's equivalent, held-out max error m)."""
    truth = load_truth(truth_path)
    robot = truth.robot
    cal = yaml.safe_load((build / "calibration.yaml").read_text())
    names = [p["name"] for p in cal["parameters"] if p["estimated"]]
    est = np.array([p["value"] for p in cal["parameters"] if p["estimated"]])
    std = np.array([p["std"] for p in cal["parameters"] if p["estimated"]])
    tracker = SimulatedTracker(robot, truth.truth, np.random.default_rng(0))
    tracker._compliance[:] = 0.0  # the geometric truth alone (compliance is scored apart)
    tracker._dyn = None
    qs = random_poses(robot, 200, np.random.default_rng(7))
    poses = [tracker.true_pose(q) for q in qs]
    exact = MeasurementSet(
        q=qs,
        position_m=np.array([m.translation for m in poses]),
        rotation=np.array([m.rotation for m in poses]),
        valid=np.ones(200, bool),
        role=("fit",) * 200,
    )
    all_names = parameter_names(robot)
    idx = np.array([all_names.index(n) for n in names])
    g = truth.truth.geometry.tracker_to_base
    t2b = placement_to_se3(g.xyz_m, g.rpy_rad)
    proj = fit_problem(robot, exact, t2b, idx, 5e-5, 1e-4, None, CalibrateSettings())
    z = (est - proj.errors.values[idx]) / std
    return float(np.max(np.abs(z))), float(cal["summary"]["heldout_max_position_error_m"])


def dynamics_z(build: Path, truth_path: Path) -> tuple[float, str, float]:
    """(max |z|, its parameter, rms z) of the base parameters against the truth's, on the kinematics
    the fit used: a fit on the prior calibration (summary.kinematics calibrated) is scored against
    the truth's bodies expressed in the calibrated link frames, through the artefact's own regrouping."""
    truth = load_truth(truth_path)
    d = yaml.safe_load((build / "dynamics.yaml").read_text())
    params, robot = truth.params, truth.robot
    if d["summary"].get("kinematics") == "calibrated":
        true = ErrorModel.from_mapping(robot, truth.truth.geometry.error_parameters).apply(robot)
        robot = load_calibrated_robot(robot, build / "calibration-prior.yaml")
        params = inertials_in_frames_of(true, robot, params)[0]
    bps = d["base_parameters"]
    names = [b["name"] for b in bps]
    full = base_parameters(truth.robot).full_names
    bset = BaseParameterSet.from_combinations(
        full, names, [b["independent"] for b in bps], [b["combination"] for b in bps]
    )
    truth_b = bset.project(params)
    est = np.array([b["value"] for b in bps])
    std = np.array([b.get("std") or b["relative_std"] * abs(b["value"]) for b in bps])
    z = (est - truth_b) / std
    worst = int(np.argmax(np.abs(z)))
    return float(np.abs(z[worst])), names[worst], float(np.sqrt(np.mean(z**2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("builds", nargs="+", type=Path)
    ap.add_argument("--robot", type=Path, default=Path("samples/rx130l"))
    args = ap.parse_args()
    truth = args.robot / "truth.yaml"
    for b in args.builds:
        print(f"== {b}")
        for r in RUNS:
            if (b / f"{r}.yaml").exists():
                s = _summary(b, r)
                print(
                    f"  {r:16s} rms lag mrad {np.round(np.array(s['rms_lag_rad']) * 1e3, 3).tolist()} "
                    f"max lag mrad {np.round(np.array(s['max_lag_rad']) * 1e3, 3).tolist()} "
                    f"max TCP mm {s['max_tcp_error_m'] * 1e3:.3f} τ RMS N·m {_torque_rms(b, r)}"
                )
        noff, ff = _summary(b, "run-noff"), _summary(b, "run-ff")
        ratio = np.array(noff["rms_lag_rad"]) / np.array(ff["rms_lag_rad"])
        print(f"  FF lag ratio (rms, noff/ff) per joint {np.round(ratio, 1).tolist()}")
        zg, held = geometry_z(b, truth)
        print(f"  calibration: held-out max {held * 1e3:.3f} mm, identifiable params max |z| {zg:.2f}")
        zd, worst, zrms = dynamics_z(b, truth)
        d = yaml.safe_load((b / "dynamics.yaml").read_text())["summary"]
        print(
            f"  dynamics: base params max |z| {zd:.2f} ({worst}), rms z {zrms:.2f}; R² {d['validation_r2']}"
        )
        c = yaml.safe_load((b / "calibration.yaml").read_text())["compliance"]
        print(f"  compliance found: {[(x['joint'], round(x['stiffness_nm_per_rad'])) for x in c]}")


if __name__ == "__main__":
    main()
