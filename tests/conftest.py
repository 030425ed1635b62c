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
