"""What a calibration or dynamics artefact claims, checked where it is loaded (issue 27).

- **Made for this robot**: the envelope's ``inputs`` hold the sha256 of the URDF and drives.yaml the
  artefact was made from; another robot's file (a longer upper arm, renamed joints that happen to
  match) is refused (InputError, exit 2) naming what differs. A stage's ``--other-robot`` accepts it
  with a warning naming the difference.
- **Physically consistent dynamics**: a model whose mass matrix M(q) is not positive definite at some
  configuration within the joint limits (64 seeded samples) makes feed-forward torques and limit
  checks meaningless: refused, or accepted with ``--allow-inconsistent`` and a warning. Slightly
  inconsistent links (`identify`'s pseudo-inertia report; the default identification's full vector
  can hold a negative wrist link mass) whose M(q) stays positive definite pass: the consumers need
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


def mass_matrix_by_rnea(dyn, q: np.ndarray) -> np.ndarray:
    """M(q) column by column from inverse dynamics at rest (τ(q, 0, e_j) − τ(q, 0, 0)): linear in the
    parameters, as the feed-forward is. (CRBA builds each link's inertia about its centre of mass and
    returns garbage, eigenvalues of 1e28, for a full vector with a negative link mass whose base
    parameters are fine.)"""
    n = q.shape[-1]
    rest = np.zeros(n)
    tau0 = dyn.inverse_dynamics(q, rest, rest)
    cols = [dyn.inverse_dynamics(q, rest, np.eye(n)[j]) - tau0 for j in range(n)]
    m = np.stack(cols, axis=-1)
    return 0.5 * (m + np.swapaxes(m, -1, -2))


def physical_problems(robot: Robot, params, n_samples: int = CONSISTENCY_SAMPLES, seed: int = 0) -> list[str]:
    """Why ``params`` (DynamicParameters) cannot drive a physical robot: a mass matrix M(q) that is not
    positive definite somewhere within the joint limits (``n_samples`` seeded configurations); [] if
    none seen. The split into links is not judged: identified base parameters fix M(q), not each
    link's mass (`identify` reports that split's consistency)."""
    from rxcomm.model.dynamics import RobotDynamics, random_states

    names = robot.joint_names
    q, _, _ = random_states(robot, n_samples, seed)
    dyn = RobotDynamics(robot, params)
    mats = np.stack([mass_matrix_by_rnea(dyn, qi) for qi in q])
    eig = np.linalg.eigvalsh(mats)
    k = int(np.argmin(eig[:, 0]))
    if eig[k, 0] > 0.0:
        return []
    diag = np.diagonal(mats[k])
    worst = int(np.argmin(diag))
    return [
        f"the mass matrix M(q) is not positive definite (least eigenvalue {eig[k, 0]:.4g}, "
        f"M[{names[worst]}] = {diag[worst]:.4g} kg·m² at q = {np.round(q[k], 3).tolist()} rad)"
    ]


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
