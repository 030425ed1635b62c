"""A stage's typer command from its declaration (`stages/declarations.py`), not a subcommand.

`stage(NAME)` makes a stage function the typer command of NAME:

- a parameter named after a declared input that every stage reading it offers with one option
  (`options.INPUT_OPTIONS`: `--dynamics`, `--payload`) and that carries no option of its own gets
  that option, so a stage lists the model it computes torques with as plain parameters;
- a declaration with `artefact_policy` adds `--other-robot` and `--allow-inconsistent`, which set
  what the stage accepts of its dynamics and calibration (`model.artefact_checks`, issue 27) before
  it runs;
- `check=True` checks the declared files, taken from the call's arguments by the declared names
  (`robot` is `robot_dir`), before the stage runs (`Declaration.check`); a stage that derives a
  file first (a default output, a required option) checks them itself;
- `signature_of=FUNCTION`: the command's options are FUNCTION's (its parameters with an option),
  for a command that only hands them to a function beside it (`run.execute`);
- an RxcommError becomes its one-line message and exit code (`console.stage_command`).

Typer reads a command's options from `inspect.signature`, which honours ``__signature__``.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable
from typing import Annotated, Any, TypeVar, get_args, get_origin

from typer.models import ParameterInfo

from rxcomm import console
from rxcomm.options import INPUT_OPTIONS, AllowInconsistent, OtherRobot
from rxcomm.stages.declarations import DECLARATIONS

T = TypeVar("T")
POLICY = ("other_robot", "allow_inconsistent")


def stage(
    name: str, *, check: bool = False, signature_of: Callable[..., Any] | None = None
) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """The decorator making a function the typer command of stage `name` (module doc)."""
    decl = DECLARATIONS[name]

    def make(fn: Callable[..., T]) -> Callable[..., T]:
        body = checking(name)(fn) if check else fn
        params = [
            _with_input_option(p, decl.inputs) for p in _signature(signature_of or fn).parameters.values()
        ]
        if signature_of is not None:  # only the options: a switch the command line does not set stays out
            params = [p for p in params if _option(p.annotation) is not None]
        if decl.artefact_policy:
            params += [_keyword(POLICY[0], OtherRobot), _keyword(POLICY[1], AllowInconsistent)]

        @functools.wraps(fn)
        def command(*args: Any, **kwargs: Any) -> T:
            if decl.artefact_policy:
                from rxcomm.model.artefact_checks import accept_artefacts

                accept_artefacts(**{k: kwargs.pop(k, False) for k in POLICY})
            return body(*args, **kwargs)

        wrapped = console.stage_command(command)
        wrapped.__signature__ = _signature(fn).replace(parameters=params)  # type: ignore[attr-defined]
        return wrapped

    return make


def checking(name: str) -> Callable[[Callable[..., T]], Callable[..., T]]:
    """`fn` with the declared files of stage `name` checked from its arguments before it runs."""
    decl = DECLARATIONS[name]
    names = {n: "robot_dir" if n == "robot" else n.replace("-", "_") for n in decl.names()}

    def make(fn: Callable[..., T]) -> Callable[..., T]:
        signature = inspect.signature(fn)  # by name only: its annotations may be for type checkers
        if missing := set(names.values()) - set(signature.parameters):
            raise TypeError(f"{fn.__qualname__} takes no {sorted(missing)}: the files {name} declares")

        @functools.wraps(fn)
        def checked(*args: Any, **kwargs: Any) -> T:
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            decl.check(**{n: bound.arguments[p] for n, p in names.items()})
            return fn(*args, **kwargs)

        return checked

    return make


def _signature(fn: Callable[..., Any]) -> inspect.Signature:
    return inspect.signature(fn, eval_str=True)


def _option(annotation: Any) -> ParameterInfo | None:
    """The typer option or argument an `Annotated` annotation carries, or None."""
    if get_origin(annotation) is not Annotated:
        return None
    return next((a for a in get_args(annotation)[1:] if isinstance(a, ParameterInfo)), None)


def _with_input_option(p: inspect.Parameter, inputs: tuple[str, ...]) -> inspect.Parameter:
    """`p` with the shared option of the declared input it names, unless it has an option of its own."""
    if p.name not in inputs or p.name not in INPUT_OPTIONS or _option(p.annotation) is not None:
        return p
    return p.replace(annotation=Annotated[p.annotation, INPUT_OPTIONS[p.name]])


def _keyword(name: str, annotation: Any) -> inspect.Parameter:
    return inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=False, annotation=annotation)
