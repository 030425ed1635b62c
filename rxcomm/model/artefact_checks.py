"""What a calibration or dynamics artefact claims, checked where it is loaded (issue 27).

- **Made for this robot**: the envelope's ``inputs`` hold the sha256 of the URDF and drives.yaml the
  artefact was made from; another robot's file (a longer upper arm, renamed joints that happen to
  match) is refused (InputError, exit 2) naming what differs. A stage's ``--other-robot`` accepts it
  with a warning naming the difference.
- **Physically consistent dynamics**: a model whose mass matrix M(q) is not positive definite at some
  configuration within the joint limits (64 seeded samples), or with a negative link mass, rotor
  inertia or friction coefficient, makes feed-forward torques and limit checks meaningless: refused,
  or accepted with ``--allow-inconsistent`` and a warning. Slightly inconsistent links
  (`identify`'s pseudo-inertia report) whose M(q) stays positive definite pass: the consumers need
  M(q) ≻ 0, not a realisable link-by-link split.

The options set a policy for the stage's duration (:func:`accepting`), so the loaders deep in the
planners need no extra arguments.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rxcomm.errors import InputError
from rxcomm.io import files
from rxcomm.model.robot import Robot
from rxcomm.schemas.plain import sha256_file

CONSISTENCY_SAMPLES = 64


@dataclass(frozen=True)
class Policy:
    other_robot: bool = False
    allow_inconsistent: bool = False


_policy: contextvars.ContextVar[Policy | None] = contextvars.ContextVar(
    "rxcomm_artefact_policy", default=None
)


def _current() -> Policy:
    return _policy.get() or Policy()


def accept_artefacts(*, other_robot: bool = False, allow_inconsistent: bool = False) -> None:
    """The policy of a stage's options for the rest of the process (the CLI runs one stage; tests
    reset it with ``accept_artefacts()``)."""
    _policy.set(Policy(other_robot, allow_inconsistent))


@contextlib.contextmanager
def accepting(*, other_robot: bool = False, allow_inconsistent: bool = False) -> Iterator[None]:
    """Within: artefacts of another robot (``other_robot``) or inconsistent dynamics are warned
    about instead of refused."""
    token = _policy.set(Policy(other_robot, allow_inconsistent))
    try:
        yield
    finally:
        _policy.reset(token)


def robot_difference(robot: Robot, inputs: Mapping[str, str]) -> str | None:
    """What differs between the robot files an artefact was made from (its envelope ``inputs``,
    name -> sha256) and ``robot``'s; None if they agree or the artefact names neither."""
    diffs = []
    for name, path in (("urdf", robot.urdf_path), ("drives", robot.drives_path)):
        want = inputs.get(name)
        if want is None:
            continue
        got = sha256_file(path)
        if want != got:
            diffs.append(f"{name}: made with sha256 {want[:12]}…, {Path(path).name} here is {got[:12]}…")
    return "; ".join(diffs) or None


def check_same_robot(robot: Robot, inputs: Mapping[str, str], file: str | Path) -> None:
    """InputError unless the artefact at ``file`` was made for ``robot``'s files (or the policy
    accepts another robot's: then a warning)."""
    diff = robot_difference(robot, inputs)
    if diff is None:
        return
    if _current().other_robot:
        files.notice(f"warning: {file} was made for other robot files ({diff}); used as --other-robot asks")
        return
    raise InputError(
        f"made for other robot files than {robot.name}'s ({diff}); pass --other-robot to use it anyway",
        file=file,
        field="inputs",
    )


def physical_problems(robot: Robot, params, n_samples: int = CONSISTENCY_SAMPLES, seed: int = 0) -> list[str]:
    """Why ``params`` (DynamicParameters) cannot be a physical robot's, worst first; [] if none seen."""
    from rxcomm.model.dynamics import RobotDynamics, random_states

    out: list[str] = []
    names = robot.joint_names
    for what, values in (
        ("link mass", params.inertial[:, 0]),
        ("rotor inertia", params.rotor_inertia_kgm2),
        ("Coulomb friction", params.coulomb_nm),
        ("viscous friction", params.viscous_nm_s_per_rad),
    ):
        for i in np.flatnonzero(np.asarray(values) < 0):
            out.append(f"{what} of {names[i]} is {float(values[i]):.4g} < 0")
    q, _, _ = random_states(robot, n_samples, seed)
    eig = np.linalg.eigvalsh(RobotDynamics(robot, params).mass_matrix(q))
    k = int(np.argmin(eig[:, 0]))
    if eig[k, 0] <= 0.0:
        diag = np.diagonal(RobotDynamics(robot, params).mass_matrix(q[k]))
        worst = int(np.argmin(diag))
        out.insert(
            0,
            f"the mass matrix M(q) is not positive definite (least eigenvalue {eig[k, 0]:.4g}, "
            f"M[{names[worst]}] = {diag[worst]:.4g} kg·m² at q = {np.round(q[k], 3).tolist()} rad)",
        )
    return out


def check_consistent(robot: Robot, params, file: str | Path) -> None:
    """InputError unless ``params`` can be a physical robot's (or the policy allows it: a warning)."""
    problems = physical_problems(robot, params)
    if not problems:
        return
    text = "; ".join(problems[:3]) + (f" (+{len(problems) - 3} more)" if len(problems) > 3 else "")
    if _current().allow_inconsistent:
        files.notice(
            f"warning: {file}: physically inconsistent dynamics ({text}); used as --allow-inconsistent asks"
        )
        return
    raise InputError(
        f"physically inconsistent dynamics: {text}; pass --allow-inconsistent to use them anyway",
        file=file,
        field="parameters",
    )
