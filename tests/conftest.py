from pathlib import Path

import pytest

from rxcomm.model.robot import load_robot

ROOT = Path(__file__).resolve().parent.parent
SAMPLES = ROOT / "samples"
ROBOT_DIRS = [SAMPLES / "rx130l", SAMPLES / "m900"]


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
