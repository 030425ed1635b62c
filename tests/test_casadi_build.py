"""One compile policy for CasADi functions: compiled and cached when a compiler exists, else the same
functions with a warning that says why."""

import logging
import shutil

import casadi as ca
import numpy as np
import pytest

from rxcomm import casadi_build


def _square_sum() -> ca.Function:
    x = ca.SX.sym("x", 3)
    return ca.Function("square_sum_test", [x], [ca.sumsqr(x) + ca.sin(x[0])])


def test_without_a_compiler_the_functions_come_back_and_a_warning_says_why(monkeypatch, tmp_path, caplog):
    monkeypatch.setenv("RXCOMM_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("PATH", str(tmp_path))  # no cc, no gcc
    monkeypatch.delenv("RXCOMM_NO_COMPILE", raising=False)
    f = _square_sum()
    with caplog.at_level(logging.WARNING, logger="rxcomm.casadi_build"):
        (g,) = casadi_build.compiled([f])
    assert g is f
    assert "no C compiler" in caplog.text
    assert not list(tmp_path.rglob("*.so"))


@pytest.mark.skipif(shutil.which("cc") is None and shutil.which("gcc") is None, reason="no C compiler")
@pytest.mark.process  # the C compiler
def test_compiled_function_matches_and_is_reused_from_the_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("RXCOMM_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("RXCOMM_NO_COMPILE", raising=False)
    f = _square_sum()
    (g,) = casadi_build.compiled([f])
    x = np.array([0.3, -1.2, 2.0])
    assert float(g(x)) == pytest.approx(float(f(x)), rel=1e-14)
    libs = sorted(tmp_path.glob("casadi/*.so"))
    assert len(libs) == 1
    mtime = libs[0].stat().st_mtime_ns
    casadi_build.compiled([f])
    assert sorted(tmp_path.glob("casadi/*.so")) == libs and libs[0].stat().st_mtime_ns == mtime
