"""The tiers' guard (tests/conftest.py): an unmarked test can start no process and open no socket, a
test marked for one can, and every marker the guard knows is registered."""

from __future__ import annotations

import socket
import subprocess
import sys
import tomllib

import pytest

from .conftest import ALLOWS, ROOT


def test_an_unmarked_test_starts_no_process_and_opens_no_socket():
    with pytest.raises(RuntimeError, match="starts a process: mark it @pytest.mark.process"):
        subprocess.run([sys.executable, "-c", "pass"])
    with socket.socket() as s, pytest.raises(RuntimeError, match="opens a socket .* @pytest.mark.socket"):
        s.bind(("127.0.0.1", 0))
    with socket.socket() as s, pytest.raises(RuntimeError, match=r"connect\).* @pytest.mark.socket"):
        s.connect(("127.0.0.1", 9))


@pytest.mark.process
def test_a_process_test_may_start_one_but_opens_no_socket():
    assert (
        subprocess.run([sys.executable, "-c", "print(6 * 7)"], capture_output=True, text=True).stdout
        == "42\n"
    )
    with socket.socket() as s, pytest.raises(RuntimeError, match="mark it @pytest.mark.socket"):
        s.bind(("127.0.0.1", 0))


@pytest.mark.socket
def test_a_socket_test_may_serve_on_loopback():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        assert s.getsockname()[1] > 0


def test_every_tier_marker_is_registered_and_the_fast_tier_excludes_each():
    markers = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["markers"]
    registered = {m.split(":")[0] for m in markers}
    assert set(ALLOWS) <= registered
    fast = next(ln for ln in (ROOT / "Makefile").read_text().splitlines() if ln.startswith("FAST :="))
    assert all(f"not {m}" in fast for m in ALLOWS), fast
