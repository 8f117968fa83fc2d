"""The conductance → force recursion compiled from C (``models/sls_inverse_kernel.c``) and called through ctypes.

Why: a process that loads numba's cached kernel pays ~0.65 s before its first sample (numba's import and its CPU
target's start-up), which is most of a one-shot ``sensnake estimate``; this library loads in ~1 ms. It is built
once per machine by the system C compiler (``$CC``, else ``cc``/``gcc``/``clang``) into the user's cache folder
(platformdirs, or ``SENSNAKE_CACHE_DIR``), named by a hash of the source and flags so an edited kernel is rebuilt, written to a
temporary name and renamed so parallel processes never load half a file. No compiler, a failed build or
``SENSNAKE_NO_CC=1``: :func:`inverse_kernel` returns None and the numba kernel (or the numpy reference) runs — same
numbers, slower start (tests hold all three to each other).

Pure numerics and a one-time build; any thread may call the kernel (no shared state).
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

SOURCE = Path(__file__).with_name("sls_inverse_kernel.c")
_COMPILERS = ("cc", "gcc", "clang")
_BUILD_TIMEOUT_S = 120.0
# -O2 without -ffast-math (NaN/inf tests inside the loop stay exact; results match numba's to ~1e-15);
# -fno-math-errno lets sqrt be one instruction (errno is never read here).
_FLAGS = ("-O2", "-fno-math-errno", "-shared", "-fPIC")

_lock = threading.Lock()
_tried = False
_kernel: Callable[..., None] | None = None
why_not: str | None = None  # after a call that returned None: the reason, for a diagnostics line


def cache_dir() -> Path:
    override = os.environ.get("SENSNAKE_CACHE_DIR")
    if override:
        return Path(override)
    import platformdirs

    return platformdirs.user_cache_path("sensnake", appauthor=False)


def _compiler() -> str | None:
    for name in ([os.environ["CC"]] if os.environ.get("CC") else []) + list(_COMPILERS):
        found = shutil.which(name)
        if found:
            return found
    return None


def _build(library: Path) -> None:
    compiler = _compiler()
    if compiler is None:
        raise OSError("no C compiler found (cc, gcc or clang)")
    library.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=library.stem, suffix=".so.tmp", dir=library.parent)
    os.close(fd)
    try:
        done = subprocess.run([compiler, *_FLAGS, "-o", tmp, str(SOURCE), "-lm"],
                              capture_output=True, text=True, timeout=_BUILD_TIMEOUT_S, check=False)
        if done.returncode != 0:
            first = (done.stderr.strip().splitlines() or ["no message"])[0]
            raise OSError(f"{Path(compiler).name} failed: {first}")
        os.replace(tmp, library)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def _load(library: Path) -> Any:
    lib = ctypes.CDLL(str(library))
    fn = lib.sls_inverse
    f64 = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
    i64 = np.ctypeslib.ndpointer(dtype=np.int64, flags="C_CONTIGUOUS")
    i8 = np.ctypeslib.ndpointer(dtype=np.int8, flags="C_CONTIGUOUS")
    c_i64, c_f64 = ctypes.c_int64, ctypes.c_double
    fn.argtypes = [c_i64, c_i64, f64, f64, f64, c_i64, c_i64, c_i64, f64, f64, f64, c_i64, c_f64, c_f64, c_f64, f64, i64,
                   f64, f64, f64, f64, i8]
    fn.restype = None
    return fn


def inverse_kernel() -> Callable[..., None] | None:
    """A callable with the signature of :func:`models.sls_kernels.inverse` running the C kernel, or None (the
    reason in :data:`why_not`). The first call on a machine builds the library (~0.3 s); later ones load it."""
    global _tried, _kernel, why_not
    if _tried:
        return _kernel
    with _lock:
        if _tried:
            return _kernel
        try:
            if os.environ.get("SENSNAKE_NO_CC", "") == "1":
                raise OSError("SENSNAKE_NO_CC=1")
            digest = hashlib.sha256(SOURCE.read_bytes() + " ".join(_FLAGS).encode()).hexdigest()[:16]
            library = cache_dir() / f"sls_inverse_{digest}.so"
            if not library.exists():
                _build(library)
            fn = _load(library)
        except (OSError, subprocess.SubprocessError) as exc:
            why_not = str(exc)
            fn = None
        _kernel = None if fn is None else _wrap(fn)
        _tried = True
        return _kernel


def _wrap(fn: Any) -> Callable[..., None]:
    def inverse(cond: np.ndarray, oma: np.ndarray, ramp: np.ndarray, use_ramp: bool, e0: np.ndarray, e1: np.ndarray,
                area: np.ndarray, contact: bool, k: float, r0: float, kc: float, strain: np.ndarray,
                strain_status: np.ndarray, q_state: np.ndarray, sig_state: np.ndarray, f_state: np.ndarray,
                force: np.ndarray, status: np.ndarray) -> None:
        s, n = cond.shape
        if oma.shape[1] != n or ramp.shape[1] != n or force.shape != (s, n) or status.shape != (s, n):
            raise ValueError("sls C kernel: array shapes do not match the conductances")
        if oma.shape[0] not in (1, s) or ramp.shape[0] not in (1, s):
            raise ValueError("sls C kernel: oma and ramp must each have one row or one row per sensor")
        if not contact and (strain.shape != (s, n) or strain_status.shape != (s, n)):
            raise ValueError("sls C kernel: strain arrays do not match the conductances")
        for name, arr in (("e0", e0), ("e1", e1), ("area", area), ("q", q_state), ("sigma", sig_state),
                          ("force_prev", f_state)):
            if arr.shape != (s,) or arr.dtype != np.float64 or not arr.flags.c_contiguous:
                raise ValueError(f"sls C kernel: {name} must be a contiguous float64 array of {s}")
        fn(s, n, cond, oma, ramp, int(oma.shape[0] == 1), int(ramp.shape[0] == 1), int(bool(use_ramp)), e0, e1, area, int(bool(contact)),
           float(k), float(r0), float(kc), strain, strain_status.astype(np.int64, copy=False), q_state, sig_state,
           f_state, force, status)

    return inverse
