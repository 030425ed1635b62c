"""Shared fixtures, and the tiers' guard.

Tiers (pyproject.toml's markers): a test that starts a process is marked `process` (`make` if it runs
make), one that serves or connects a socket `socket`, one whose figures need wall-clock streaming on a
quiet machine `realtime`, a long one (end to end on the simulated cell, a full solve) `slow`.
`make test-fast` runs the unmarked rest, the unit tier. The guard below holds the markers true: an
unmarked test that starts a process or opens a socket fails at once, saying which marker it needs
(`slow` tests may do anything).
"""

import os
import socket
import subprocess
from pathlib import Path

import pytest

from rxcomm.code_identity import code_identity
from rxcomm.model.robot import load_robot

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples"
ROBOT_DIRS = [SAMPLES / "rx130l", SAMPLES / "m900"]

# What each marker allows the guard to let through.
ALLOWS = {
    "slow": {"process", "socket"},
    "make": {"process"},
    "process": {"process"},
    "socket": {"socket"},
    "realtime": {"socket"},
}
EVERYTHING = {"process", "socket"}

code_identity()  # once, before any guard: the envelope of every artefact asks git for it

# What the test being set up or run may do. The guard is installed once for the session and asks this,
# so a module- or session-scoped fixture (a served cell) is held to the test that first needs it;
# outside a test's setup and call (collection, teardown) everything is allowed.
_allowed: set[str] = set(EVERYTHING)


def _guarded(original, what: str, need: str):
    def guarded(*args, **kwargs):
        if need not in _allowed:
            raise RuntimeError(f"this test {what}: mark it @pytest.mark.{need} (tests/conftest.py, tiers)")
        return original(*args, **kwargs)

    return guarded


def pytest_configure(config):
    subprocess.Popen._execute_child = _guarded(subprocess.Popen._execute_child, "starts a process", "process")
    os.fork = _guarded(os.fork, "forks a process", "process")
    os.posix_spawn = _guarded(os.posix_spawn, "spawns a process", "process")
    for name in ("bind", "connect", "connect_ex"):
        original = getattr(socket.socket, name)
        setattr(socket.socket, name, _guarded(original, f"opens a socket ({name})", "socket"))


_NO_COMPILE = os.environ.get("RXCOMM_NO_COMPILE")


def _allow(item) -> None:
    """Also: a test that may not start a process gets CasADi's virtual machine (rxcomm.casadi_build runs
    no C compiler: `RXCOMM_NO_COMPILE`), whatever the on-disk cache holds; set here, before any of its
    fixtures, so that a module-scoped one is held to it too (on a fresh machine's empty cache it would
    otherwise start the compiler)."""
    global _allowed
    _allowed = set().union(*(ALLOWS.get(m.name, set()) for m in item.iter_markers()))
    if "process" in _allowed and _NO_COMPILE is None:
        os.environ.pop("RXCOMM_NO_COMPILE", None)
    else:
        os.environ["RXCOMM_NO_COMPILE"] = _NO_COMPILE or "1"


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    _allow(item)
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_call(item):
    _allow(item)
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item):
    global _allowed
    _allowed = set(EVERYTHING)  # stopping what a marked test's fixture started
    yield


@pytest.fixture(scope="session")
def rx130l():
    return load_robot(SAMPLES / "rx130l")


@pytest.fixture(scope="session")
def m900():
    return load_robot(SAMPLES / "m900")


@pytest.fixture(scope="session", params=["rx130l", "m900"])
def robot(request):
    return load_robot(SAMPLES / request.param)


@pytest.fixture(autouse=True)
def _release_output_locks():
    """Stages called as functions keep their outputs' locks (the CLI releases them on exit): release
    them after each test, so a later subprocess may write the same file."""
    from rxcomm.io.files import release_outputs

    yield
    release_outputs()


@pytest.fixture(autouse=True)
def _strict_artefacts():
    """`--other-robot` / `--allow-inconsistent` set a process-wide policy: back to strict after each test."""
    from rxcomm.model.artefact_checks import accept_artefacts

    yield
    accept_artefacts()
