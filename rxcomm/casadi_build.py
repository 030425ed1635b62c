"""CasADi functions compiled to C once per content and cached (used by excitation and the PtP OCP).

Generated C is compiled with the system compiler into a shared library named by the hash of its code
and flags, in ``$RXCOMM_CACHE_DIR/casadi`` (default ``~/.cache/rxcomm/casadi``), and loaded back with
``casadi.external``: 3–10× faster derivatives than CasADi's SX virtual machine. One policy when that is
not possible (no C compiler, no writable cache, a compiler error, or ``RXCOMM_NO_COMPILE=1``): the
functions are used as they are — same results, slower — and a warning says so and why.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

log = logging.getLogger(__name__)
COMPILE_TIMEOUT_S = 300.0


def cache_dir() -> Path:
    return Path(os.environ.get("RXCOMM_CACHE_DIR") or Path.home() / ".cache" / "rxcomm") / "casadi"


def _fallback(reason: str, functions: list[ca.Function]) -> list[ca.Function]:
    log.warning("CasADi functions not compiled (%s): using the slower virtual machine", reason)
    return functions


def compiled(functions: list[ca.Function], flags: tuple[str, ...] = ("-O1",)) -> list[ca.Function]:
    """`functions` as compiled externals, built in parallel and reused from the cache; see the module
    docstring for what happens when they cannot be compiled."""
    if os.environ.get("RXCOMM_NO_COMPILE"):
        return functions  # asked for: nothing to warn about
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        return _fallback("no C compiler (cc or gcc) on PATH", functions)
    cache = cache_dir()
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        return _fallback(f"cache {cache} not writable: {e.strerror}", functions)
    jobs = []
    for f in functions:
        cg = ca.CodeGenerator(f"{f.name()}.c", {"with_header": False})
        cg.add(f)
        code = cg.dump()
        key = hashlib.sha256((code + " ".join(flags)).encode()).hexdigest()[:20]
        so = cache / f"{f.name()}_{key}.so"
        if so.exists():
            jobs.append((f, so, None, None))
            continue
        fd, c_path = tempfile.mkstemp(suffix=".c", dir=cache)
        with os.fdopen(fd, "w") as fh:
            fh.write(code)
        part = so.with_name(f"{so.name}.{os.getpid()}.part")
        proc = subprocess.Popen(
            [cc, *flags, "-shared", "-fPIC", "-o", str(part), c_path],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        jobs.append((f, so, proc, (c_path, part)))
    out = []
    for f, so, proc, paths in jobs:
        if proc is not None:
            _, err = proc.communicate(timeout=COMPILE_TIMEOUT_S)
            c_path, part = paths
            Path(c_path).unlink(missing_ok=True)
            if proc.returncode != 0:
                part.unlink(missing_ok=True)
                out.extend(_fallback(f"{cc} failed on {f.name()}: {err.strip()[-200:]}", [f]))
                continue
            os.replace(part, so)  # atomic: a concurrent reader sees the whole file or none
        out.append(ca.external(f.name(), str(so)))
    return out


class Mapped:
    """A CasADi function mapped over k samples and evaluated in place on numpy arrays (CasADi's
    buffer interface: no DM conversion, which costs more than the evaluation itself here).

    CasADi stores matrices column-major, so the mapped input of an (r × 1) argument, r × k, is a
    C-order [k, r] array (sample-major), and the mapped output of an (r × c) result is a C-order
    [k, c, r] array. Outputs must be dense (`ca.densify`). The returned arrays are reused by the
    next call: copy what you keep."""

    def __init__(self, f: ca.Function, k: int):
        self.k = k
        self._f = f.map(k)
        self._buf, self._eval = self._f.buffer()
        self._args = [np.zeros(self._f.nnz_in(i)) for i in range(self._f.n_in())]
        self._res = []
        for i in range(self._f.n_out()):
            if self._f.nnz_out(i) != self._f.numel_out(i):
                raise ValueError(f"output {i} of {f.name()} is sparse: densify it")
            self._res.append(np.zeros(self._f.nnz_out(i)))
        for i, arr in enumerate(self._args):
            self._buf.set_arg(i, memoryview(arr))
        for i, arr in enumerate(self._res):
            self._buf.set_res(i, memoryview(arr))
        self._shapes = [(k, f.size2_out(i), f.size1_out(i)) for i in range(f.n_out())]

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        for arr, x in zip(self._args, inputs, strict=True):
            arr[:] = np.ravel(x)
        self._eval()
        return [r.reshape(shape) for r, shape in zip(self._res, self._shapes, strict=True)]
