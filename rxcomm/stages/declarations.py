"""One declaration per stage: the files it reads and writes, what its output is, its settings model.

The one place a stage's file shape is written (architecture §7). From it come the stage's output
checks (`Declaration.check`: every file it reads and writes, declared or refused) and the report's
artefact list (`stages/report.py`: the schema and plot of each artefact it reads by name);
`tests/test_stage_declarations.py` holds the Makefile's chain rules to it: each rule lists as
prerequisites exactly the files its command reads, and writes the output its command declares.

Names are the command line's: an input or output is named by its option without the dashes
(`dynamics` for `--dynamics`, `urdf-out`), or by its argument (`plan`); `robot` stands for the robot
directory's files (drives.yaml and its URDF), `output` for `-o`. Imports no library: `--help` and the
report read it.
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel

from rxcomm.schemas.acceptance import Acceptance
from rxcomm.schemas.calibration import Calibration
from rxcomm.schemas.configs import Configs
from rxcomm.schemas.dynamics import Dynamics
from rxcomm.schemas.envelope import Artefact
from rxcomm.schemas.excitation import Excitation
from rxcomm.schemas.iso9283 import Iso9283
from rxcomm.schemas.measurements import Measurements
from rxcomm.schemas.payload import Payload
from rxcomm.schemas.run_log import RunLog
from rxcomm.schemas.trajectory import TrajectorySummary

FileArg = str | Path | None


@dataclass(frozen=True)
class Beside:
    """A file a stage writes beside one of its outputs: the output's name with another suffix."""

    name: str  # as `check_outputs` names it in a message
    suffix: str  # ".png"; "-trajectory.mcap" replaces the suffix and extends the stem
    when: str | None = None  # the switch that makes it (e.g. "plot"); None: always
    of: str = "output"  # the output it stands beside

    def path(self, output: str | Path) -> Path:
        p = Path(output)
        return (
            p.with_suffix(self.suffix) if self.suffix.startswith(".") else p.with_name(p.stem + self.suffix)
        )


PLOT = Beside("plot", ".png", when="plot")


@dataclass(frozen=True)
class Declaration:
    """What a stage reads and writes. `kinds`: the schemas of what `-o` writes (of NAME.yaml, or of the
    summary NAME.yaml beside NAME.mcap), the usual one first; empty: not an artefact."""

    inputs: tuple[str, ...]
    kinds: tuple[type[Artefact], ...] = ()
    suffixes: tuple[str, ...] = (".yaml",)  # what -o may end in; "/": a directory, "": standard output
    outputs: tuple[str, ...] = ()  # further output options, e.g. "urdf-out"
    beside: tuple[Beside, ...] = ()
    positional: tuple[str, ...] = ()  # inputs given as arguments (in this order), not as options
    defaults: tuple[Beside, ...] = ()  # further outputs that default to a file beside -o
    # The settings model, "module:Class" under rxcomm: named, not imported, so that a command's code
    # identity (rxcomm/code_identity.py reads module names) covers only what it runs; tests resolve it.
    settings: str | None = None
    # --other-robot / --allow-inconsistent: its dynamics and calibration may claim another robot, or
    # physically inconsistent dynamics, when asked (issue 27; stages/stage_cli.py adds both options).
    artefact_policy: bool = False

    @property
    def kind(self) -> type[Artefact] | None:
        return self.kinds[0] if self.kinds else None

    def names(self) -> set[str]:
        """Every keyword `check` takes."""
        switches = {b.when for b in self.beside if b.when is not None}
        return {*self.inputs, "output", *self.outputs} | switches

    def written(self, **files: FileArg | bool) -> dict[str, Path | None]:
        """The files written, by name: `output`, the further outputs and the files beside them."""
        files = _dashed(files)
        out: dict[str, FileArg] = {"output": files.get("output")}
        out |= {name: files.get(name) for name in self.outputs}
        for d in self.defaults:
            if out[d.name] is None and out[d.of] is not None:
                out[d.name] = d.path(out[d.of])  # type: ignore[arg-type]
        for b in self.beside:
            of = out.get(b.of)
            made = of is not None and (b.when is None or bool(files.get(b.when)))
            out[b.name] = b.path(of) if made else None  # type: ignore[arg-type]
        return {k: None if v is None else Path(v) for k, v in out.items()}

    def read(self, **files: FileArg | Sequence[FileArg] | bool) -> dict[str, FileArg]:
        """The files read, by name: a list input numbered, `robot` as its files."""
        files = _dashed(files)
        from rxcomm.model.robot import robot_files

        out: dict[str, FileArg] = {}
        for name in self.inputs:
            value = files.get(name)
            if name == "robot":
                out |= robot_files(value) if value is not None else {}  # type: ignore[arg-type]
            elif isinstance(value, list | tuple):
                out |= {f"{name} {i + 1}": p for i, p in enumerate(value)}
            else:
                out[name] = value  # type: ignore[assignment]
        return out

    def check(self, **files: FileArg | Sequence[FileArg] | bool) -> dict[str, Path]:
        """`check_outputs` (a directory output: `check_output_dir`) on exactly the declared files, before
        any work. Keywords: every name of `names()` (dashes as underscores); another is a TypeError."""
        from rxcomm.io.files import check_output_dir, check_outputs

        given = _dashed(files)
        if set(given) != self.names():
            raise TypeError(f"undeclared {set(given) - self.names()}, missing {self.names() - set(given)}")
        if self.suffixes == ("/",):
            return {"output": check_output_dir(given["output"], "output", self.read(**given))}  # type: ignore[arg-type]
        return check_outputs(self.written(**given), self.read(**given))

    def settings_model(self) -> type[BaseModel] | None:
        if self.settings is None:
            return None
        module, _, name = self.settings.partition(":")
        return getattr(importlib.import_module(f"{__package__.split('.')[0]}.{module}"), name)


def _dashed(files: dict) -> dict:
    return {k.replace("_", "-"): v for k, v in files.items()}


TRAJECTORY = {"kinds": (TrajectorySummary,), "suffixes": (".mcap",)}
DECLARATIONS: dict[str, Declaration] = {
    "robot-info": Declaration(("robot",), suffixes=("",)),
    "select-configs": Declaration(("robot", "cell"), (Configs,), beside=(PLOT,)),
    "calibrate": Declaration(
        ("robot", "measurements", "cell", "dynamics"),
        (Calibration,),
        outputs=("urdf-out", "mdh-out"),
        beside=(Beside("mdh-out CSV", ".csv", of="mdh-out"),),
        settings="calibration.settings:CalibrateSettings",
    ),
    "excite": Declaration(
        ("robot", "cell"),
        (Excitation,),
        outputs=("trajectory-out",),
        beside=(PLOT,),
        defaults=(Beside("trajectory-out", "-trajectory.mcap"),),  # excitation-trajectory.mcap
        settings="schemas.excitation:ExcitationSettings",
    ),
    "identify": Declaration(
        ("robot", "log", "validate", "calibration"),
        (Dynamics,),
        outputs=("torques-out", "params-out"),
        beside=(PLOT,),
        settings="identification.settings:IdentifySettings",
    ),
    "score": Declaration(
        ("robot", "dynamics", "log", "calibration"),
        (Dynamics,),
        outputs=("torques-out",),
        settings="identification.settings:IdentifySettings",
    ),
    "identify-payload": Declaration(
        ("robot", "log", "dynamics", "validate"),
        (Payload,),
        beside=(PLOT,),
        settings="identification.settings:IdentifySettings",
    ),
    "plan-cp": Declaration(
        ("robot", "path", "dynamics", "payload", "calibration"),
        **TRAJECTORY,
        beside=(PLOT,),
        settings="planning.cp:CpSettings",
        artefact_policy=True,
    ),
    "iso9283-paths": Declaration(("robot", "cell"), suffixes=("/",)),
    "plan-ptp": Declaration(
        ("robot", "dynamics", "payload", "calibration"),
        **TRAJECTORY,
        beside=(PLOT,),
        settings="planning.ptp_problem:PtpOptions",
        artefact_policy=True,
    ),
    "plan-poses": Declaration(("robot", "paths", "calibration", "dynamics"), **TRAJECTORY),
    "plan-cycles": Declaration(("robot", "plan", "dynamics", "payload"), **TRAJECTORY, positional=("plan",)),
    "run": Declaration(
        ("robot", "plan", "dynamics", "payload", "truth", "truth-payload", "compare", "calibration"),
        (RunLog, Measurements),
        suffixes=(".mcap", ".yaml"),  # a trajectory's run log; a pose list's measurements
        beside=(PLOT,),
        positional=("plan",),
        settings="execution.session:RunSettings",
        artefact_policy=True,
    ),
    "iso9283": Declaration(
        ("robot", "pose-log", "line-log", "circle-log", "small-circle-log", "rectangle-log")
        + ("paths", "calibration", "cell"),
        (Iso9283,),
        beside=(PLOT,),
        settings="acceptance.campaign:EvaluationSettings",
    ),
    "accept": Declaration(
        (
            "thresholds",
            "factory-log",
            "commissioned-log",
            "commissioned-equal-time-log",
            "commissioned-curve-log",
        )
        + ("factory-iso9283", "commissioned-iso9283"),
        (Acceptance,),
    ),
    "export": Declaration(
        ("artefacts", "robot", "calibration"), suffixes=("/", ""), positional=("artefacts",)
    ),
    "report": Declaration(
        ("build-dir",), suffixes=(".md",), beside=(Beside("html", ".html"),), positional=("build-dir",)
    ),
    "recover-log": Declaration(("part",), (RunLog,), suffixes=(".mcap",), positional=("part",)),
    "import-tracker": Declaration(
        ("log", "tracker-csv", "robot"), (RunLog,), (".mcap",), positional=("log",)
    ),
    "truth": Declaration(("robot",)),
    "import-robot": Declaration(("model",), suffixes=("/",), positional=("model",)),
    "cell-sim": Declaration(("truth", "cell"), suffixes=(), settings="cell.sim:SimSettings"),
}
