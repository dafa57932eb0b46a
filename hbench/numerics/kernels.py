"""Compiled kernels for the loops numpy cannot vectorise well, and the switch to the numpy path.

``hbench/numerics/_kernels.c`` is built by ``pip install`` as an optional extension (``setup.py``);
this module loads it through :mod:`ctypes`. Each kernel performs the floating-point operations of
the numpy path it stands for, in the same order and without fused multiply-adds, so **both paths
give the same numbers** (equal as floats; only the sign of an exact zero, or of a nan, may differ;
checked by ``tests/test_kernels.py`` for every built-in actuator, controllers of 0-3 states and
plants of order 1-3): the compiled one is only faster. A run's numbers never depend on the runs
batched with it.

* ``HBENCH_KERNELS=numpy`` (environment) forces the numpy path; ``auto`` (default) uses the
  compiled kernels when they were built. :func:`use` switches for the calling thread or task
  (tests).
* Without a C compiler at install time, or with a stale build (compiled from another
  ``_kernels.c`` than the one beside this module: ``setup.py`` compiles the source's SHA-256
  into the library), hbench runs the numpy path; :func:`backend` says which one runs, and
  ``hbench plugins`` and every run's ``provenance.json`` say it.

Kernels:

* :func:`hbench.sim.loop_kernel.closed_loop` (the call is there):
  :func:`hbench.sim.simulate._run_loop` for the built-in actuators
  (:data:`hbench.sim.loop_kernel.NONLINEARITY_CODES`) and the state-space controllers of
  :mod:`hbench.model.controllers`; other actuators (plugins) run the numpy loop.
* :func:`filtered_output`: ``w = A(q) y`` of :func:`hbench.ident.polyphase.filtered_output`.
* :func:`period_mean_squares`: ``Var{Delta w^(l)}`` of
  :func:`hbench.ident.polyphase.phase_variances`.
* :func:`lfilter_rows`: ``scipy.signal.lfilter`` with one coefficient set per run
  (:func:`hbench.ident.polyphase.batched_lfilter`, Bai & Fu's direct inverse).
* :func:`inner_signal_ls`: eq. (27) of :func:`hbench.ident.polyphase.inner_signal_ls`, its normal
  equations formed and solved with LAPACK ``dptsv``'s arithmetic (reference ``dpttrf`` and
  ``dpttrs``, which the numpy path calls).
* :func:`backlash_rows`, :func:`stiction_rows`: the diagnosis's actuator maps for a batch of
  candidate parameters (:func:`hbench.diagnose.core.backlash_batch`,
  :func:`hbench.diagnose.core.stiction_batch`), one step per input sample.
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import functools
import hashlib
import importlib.util
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from hbench.errors import InputError

BACKENDS = ("auto", "numpy")


_F64 = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS,ALIGNED")
_U8 = np.ctypeslib.ndpointer(dtype=np.uint8, flags="C_CONTIGUOUS,ALIGNED")
_I64 = ctypes.c_int64
#: The backend :func:`use` asked for in this context (a context variable, so a thread's or
#: task's ``use`` leaves the others alone); ``None``: ``HBENCH_KERNELS``.
_override: contextvars.ContextVar[str | None] = contextvars.ContextVar(
    "hbench_kernels", default=None
)


def _asked() -> str:
    """The backend asked for: :func:`use`'s, else ``HBENCH_KERNELS`` (default ``auto``)."""
    name = _override.get()
    return os.environ.get("HBENCH_KERNELS", "auto") if name is None else name


@functools.cache
def _library() -> tuple[ctypes.CDLL | None, str]:
    """The compiled library and a note on why it is absent (``""`` when loaded)."""
    spec = importlib.util.find_spec("hbench.numerics._kernels")
    if spec is None or spec.origin is None:
        return None, "not built (no C compiler at install time?): the numpy path runs"
    lib = ctypes.CDLL(spec.origin)
    try:
        lib.hb_source_sha256.restype = ctypes.c_char_p
        built = lib.hb_source_sha256().decode()
    except AttributeError:  # an older build, or symbols not exported
        built = "unknown"
    source = Path(__file__).with_name("_kernels.c")
    if source.exists() and built != hashlib.sha256(source.read_bytes()).hexdigest():
        return None, (
            "stale build (hbench/numerics/_kernels.c changed since it was compiled): run "
            "`pip install -e .` again; the numpy path runs"
        )
    lib.hb_closed_loop.restype = ctypes.c_int
    lib.hb_closed_loop.argtypes = [
        *(_I64,) * 4,
        *(_F64,) * 4,
        _I64,
        *(_F64,) * 3,
        ctypes.c_double,
        _I64,
        _I64,
        *(_F64,) * 7,
    ]
    lib.hb_filtered_output.restype = None
    lib.hb_filtered_output.argtypes = [*(_I64,) * 3, _F64, _F64, _F64, ctypes.c_void_p]
    lib.hb_period_mean_squares.restype = None
    lib.hb_period_mean_squares.argtypes = [*(_I64,) * 4, ctypes.c_void_p, _I64, _F64]
    lib.hb_filtered_phase_variances.restype = None
    lib.hb_filtered_phase_variances.argtypes = [*(_I64,) * 3, _F64, _F64, *(_I64,) * 3, _F64]
    lib.hb_fitness.restype = None
    lib.hb_fitness.argtypes = [*(_I64,) * 2, *(_F64,) * 6]
    lib.hb_lfilter_rows.restype = ctypes.c_int
    lib.hb_lfilter_rows.argtypes = [*(_I64,) * 3, _F64, _F64, ctypes.c_void_p, _I64, _F64]
    lib.hb_inner_signal_ls.restype = ctypes.c_int
    lib.hb_inner_signal_ls.argtypes = [*(_I64,) * 3, _F64, *(_I64,) * 2, _U8, _F64, _F64, _F64]
    lib.hb_backlash_rows.restype = None
    lib.hb_backlash_rows.argtypes = [*(_I64,) * 2, *(_F64,) * 5]
    lib.hb_stiction_rows.restype = None
    lib.hb_stiction_rows.argtypes = [*(_I64,) * 2, _F64, ctypes.c_double, *(_F64,) * 6, _U8, _F64]
    return lib, ""


def backend() -> str:
    """``"c"`` when the compiled kernels run, else ``"numpy"``."""
    asked = _asked()
    if asked not in BACKENDS:
        raise InputError(f"HBENCH_KERNELS must be one of {', '.join(BACKENDS)}, got {asked!r}")
    if asked == "numpy":
        return "numpy"
    return "c" if _library()[0] is not None else "numpy"


def built() -> bool:
    """Whether the compiled library is built and loads (whatever the backend switch)."""
    return _library()[0] is not None


def status(own_route: Sequence[str] = ()) -> str:
    """One line for people: which path runs and why; ``own_route``: the computations numpy or
    scipy run although the kernels do, because this machine's libraries compute otherwise
    (:func:`hbench.bench.kernel_status.status` finds them)."""
    b = backend()
    if b == "c":
        if own_route:  # fused multiply-adds in the libraries: their own routes keep both equal
            return (
                "compiled kernels (hbench.numerics._kernels); numpy/scipy for "
                + ", ".join(own_route)
                + ", which compute otherwise than the kernels"
            )
        return "compiled kernels (hbench.numerics._kernels)"
    why = "HBENCH_KERNELS=numpy" if _asked() == "numpy" else _library()[1]
    return f"numpy path ({why})"


@contextlib.contextmanager
def use(name: str) -> Iterator[None]:
    """Run the body with the backend ``name`` (``"auto"`` or ``"numpy"``), in this thread (or
    task) only; processes forked within the body inherit it."""
    if name not in BACKENDS:
        raise InputError(f"kernel backend must be one of {', '.join(BACKENDS)}, got {name!r}")
    token = _override.set(name)
    try:
        yield
    finally:
        _override.reset(token)


def active_library() -> ctypes.CDLL | None:
    """The library when the compiled kernels run (:func:`backend` is ``"c"``), else None."""
    return _library()[0] if backend() == "c" else None


def as_f64(a: Any) -> np.ndarray:
    """``a`` as C-ordered, aligned float64 (a copy only where it is not already)."""
    return np.require(a, np.float64, ("C", "A"))


def filtered_output(y: np.ndarray, a: np.ndarray) -> np.ndarray | None:
    """``w = A(q) y`` per run, compiled; ``None`` when the numpy path must run (it also
    serves shapes the kernel does not take, e.g. one coefficient row broadcast to all runs)."""
    out = _filtered_output(y, a, False)
    return None if out is None else out[0]


def filtered_output_and_delta(y: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """``(w, delta(w))`` (:func:`hbench.ident.polyphase.delta`) in one compiled pass per run;
    ``None`` when the numpy path must run."""
    return _filtered_output(y, a, True)


def _filtered_output(
    y: np.ndarray, a: np.ndarray, with_delta: bool
) -> tuple[np.ndarray, np.ndarray | None] | None:
    lib = active_library()
    if lib is None or y.ndim != 2 or a.ndim != 2 or a.shape[0] != y.shape[0] or a.shape[1] < 1:
        return None
    y, a = as_f64(y), as_f64(a)
    R, N = y.shape
    w = np.empty((R, N))
    dw = np.empty((R, N)) if with_delta else None
    lib.hb_filtered_output(R, N, a.shape[1] - 1, a, y, w, None if dw is None else dw.ctypes.data)
    return w, dw


def period_mean_squares(block: np.ndarray) -> np.ndarray | None:
    """``np.mean(np.square(block), axis=1)`` for ``block`` of shape ``(runs, n, width)``, a
    strided view with unit element stride (:func:`hbench.ident.polyphase.period_block`), compiled;
    ``None`` when numpy must run (numpy path, ``width < 2``, no periods, another layout)."""
    lib = active_library()
    if lib is None or block.ndim != 3 or block.dtype != np.float64:
        return None
    R, n, width = block.shape
    s0, s1, s2 = block.strides
    if width < 2 or n < 1 or R < 1 or s2 != 8 or s1 % 8 or s0 % 8 or s1 < 8 * width:
        return None
    out = np.empty((R, width))
    lib.hb_period_mean_squares(R, n, s1 // 8, width, block.ctypes.data, s0 // 8, out)
    return out


def filtered_phase_variances(
    y: np.ndarray, a: np.ndarray, p: int, t0: int, n: int
) -> np.ndarray | None:
    """``(1/n) sum_j dw(t0 + j p + l)^2`` for ``l = 0 .. p - 1``, ``dw = delta(A(q) y)`` per run
    (what :func:`hbench.ident.polyphase.phase_variances` computes from :func:`filtered_output`'s
    ``w``), compiled without forming ``w`` or ``dw``: the same operations in the same order.
    ``None`` when numpy must run (numpy path, ``p < 2`` where numpy sums pairwise, ``p > 64``,
    no period, or a window that reaches an undefined ``w``)."""
    lib = active_library()
    if lib is None or y.ndim != 2 or a.ndim != 2 or a.shape[0] != y.shape[0] or a.shape[1] < 1:
        return None
    R, N = y.shape
    na = a.shape[1] - 1
    if not 2 <= p <= 64 or n < 1 or t0 - 1 < na or t0 + n * p > N:
        return None
    y, a = as_f64(y), as_f64(a)
    out = np.empty((R, p))
    lib.hb_filtered_phase_variances(R, N, na, a, y, p, t0, n, out)
    return out


def fitness(
    U_est: np.ndarray, U: np.ndarray, gain: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`hbench.bench.metrics.fitnesses` under the scalings ``"gain"`` and ``"ls"``, compiled:
    ``(F_gain, F_ls)`` per run. ``None`` when numpy must run: numpy path, inputs that are not
    C-ordered float64 rows of one shape (numpy would sum them in another order). Where numpy's row
    sums are not the kernel's, the caller keeps to numpy
    (:func:`hbench.bench.metrics.sums_are_numpys`)."""
    if active_library() is None:
        return None
    return fitness_built(U_est, U, gain)


def fitness_built(
    U_est: np.ndarray, U: np.ndarray, gain: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`fitness` with the built library whatever the backend switch (its self-check's)."""
    lib = _library()[0]
    if lib is None or U_est.ndim != 2 or U.shape != U_est.shape or U.shape[1] < 1:
        return None
    for a in (U_est, U):  # exactly ndarrays: a masked array or matrix keeps its own rules
        if type(a) is not np.ndarray or a.dtype != np.float64 or not a.flags.c_contiguous:
            return None
        if not a.flags.aligned:
            return None
    R, K = U.shape
    g = np.ascontiguousarray(np.broadcast_to(np.asarray(gain, float), (R,)))
    out_gain, out_ls = np.empty(R), np.empty(R)
    lib.hb_fitness(R, K, U_est, U, g, out_gain, out_ls, np.empty(3 * K))
    return out_gain, out_ls


def lfilter_rows(num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray | None:
    """``scipy.signal.lfilter(num[r], den[r], x[r])`` for every run, from rest, compiled;
    ``None`` when scipy must run (numpy path, a denominator of length 1, more than 64
    coefficients, or a scipy whose ``lfilter`` does not compute as the kernel does: see
    :func:`lfilter_is_scipys`)."""
    if active_library() is None or not lfilter_is_scipys():
        return None
    return _lfilter_rows(num, den, x)


@functools.cache
def lfilter_is_scipys() -> bool:
    """Whether the kernel of :func:`lfilter_rows` gives ``scipy.signal.lfilter``'s numbers here
    (scipy built without fused multiply-adds), checked once per process on a fixed filter; where
    it does not, scipy filters on both backends (the noise shaping and Bai & Fu's inverse), so
    they still agree. Like :func:`lapack_is_reference`, independent of the backend switch."""
    from scipy import signal

    rng = np.random.default_rng(11)
    x = rng.standard_normal((3, 400)) * np.exp(rng.uniform(-5, 5, (3, 1)))
    num = rng.standard_normal((3, 3))
    den = np.concatenate([1.0 + rng.random((3, 1)), 0.4 * rng.standard_normal((3, 3))], axis=1)
    got = _lfilter_rows(num, den, x)
    want = np.stack([signal.lfilter(num[r], den[r], x[r]) for r in range(3)])
    return got is not None and bool(np.array_equal(got, want))


def _lfilter_rows(num: np.ndarray, den: np.ndarray, x: np.ndarray) -> np.ndarray | None:
    lib = _library()[0]  # the build, whatever the switch (the public wrapper reads that)
    if lib is None or x.ndim != 2 or num.ndim != 2 or den.ndim != 2:
        return None
    n = max(num.shape[1], den.shape[1])
    R, N = x.shape
    if num.shape[0] != R or den.shape[0] != R or num.shape[1] < 1 or den.shape[1] < 2 or n > 64:
        return None
    if not np.all(den[:, 0] != 0):  # scipy refuses a[0] == 0: let it say so
        return None
    b = np.zeros((R, n))
    a = np.zeros((R, n))
    b[:, : num.shape[1]] = num
    a[:, : den.shape[1]] = den
    x = np.asarray(x, dtype=np.float64)
    if x.strides[1] != 8 or x.strides[0] % 8:
        x = np.ascontiguousarray(x)
    y = np.empty((R, N))
    rc = lib.hb_lfilter_rows(R, N, n, b, a, x.ctypes.data, x.strides[0] // 8, y)
    if rc != 0:
        raise RuntimeError(f"hb_lfilter_rows failed with code {rc}")
    return y


def inner_signal_ls(
    W: np.ndarray,
    valid: np.ndarray,
    h0: np.ndarray,
    h1: np.ndarray,
    *,
    start: int | None = None,
) -> np.ndarray | None:
    """``U~`` of eq. (27) (:func:`hbench.ident.polyphase.inner_signal_ls`) from the SIMO blocks
    ``W`` ``(runs, M, p)`` (or, with ``start``, from the rows of ``w`` ``(runs, N)`` read in place:
    ``W[:, k, i] = w[:, start + k p + i]``), their validity ``(M, p)`` and the channel coefficients
    ``(runs, p)``, compiled; ``None`` when the numpy path must run (also where this machine's LAPACK
    ``dptsv`` does not compute as the reference ``dpttrf``/``dpttrs`` the kernel mirrors, the caller
    keeps to numpy: see :func:`hbench.ident.polyphase.lapack_is_reference`). Entries that are not
    ``valid`` are taken as 0, never read."""
    if active_library() is None:
        return None
    return inner_signal_ls_built(W, valid, h0, h1, start)


def inner_signal_ls_built(
    W: np.ndarray,
    valid: np.ndarray,
    h0: np.ndarray,
    h1: np.ndarray,
    start: int | None = None,
) -> np.ndarray | None:
    """:func:`inner_signal_ls` with the built library whatever the backend switch."""
    lib = _library()[0]  # the build, whatever the switch (the public wrapper reads that)
    if lib is None or valid.ndim != 2 or h0.ndim != 2 or h1.ndim != 2:
        return None
    M, p = valid.shape
    R = W.shape[0]
    if start is None:  # the blocks
        if W.shape != (R, M, p):
            return None
        start, row_stride = 0, M * p
    else:  # the rows of w: every valid sample must lie in them
        if W.ndim != 2 or start < 0:
            return None
        cells = np.flatnonzero(valid)
        if cells.size and start + int(cells[-1]) >= W.shape[1]:  # flat index k p + i
            return None
        row_stride = W.shape[1]
    if h0.shape != (R, p) or h1.shape != (R, p) or p < 1:
        return None
    U = np.empty((R, M + 1))
    rc = lib.hb_inner_signal_ls(
        R,
        M,
        p,
        as_f64(W),
        row_stride,
        int(start),
        np.ascontiguousarray(valid, dtype=np.uint8),
        as_f64(h0),
        as_f64(h1),
        U,
    )
    if rc != 0:
        raise RuntimeError(f"hb_inner_signal_ls failed with code {rc}")
    return U


def _rows(x: np.ndarray, *cols: np.ndarray) -> tuple[np.ndarray, ...] | None:
    """``x`` as a float64 vector and ``cols`` as float64 vectors of one length, fresh copies
    (the kernels update some in place); ``None`` when the shapes are not those."""
    x = np.asarray(x)
    if x.ndim != 1 or x.dtype != np.float64:
        return None
    out = tuple(np.array(c, dtype=np.float64, order="C", copy=True).reshape(-1) for c in cols)
    if not out or any(c.size != out[0].size for c in out):
        return None
    return (as_f64(x), *out)


def backlash_rows(x: np.ndarray, half: np.ndarray, u0: np.ndarray) -> np.ndarray | None:
    """The play operator of :func:`hbench.diagnose.core.backlash_batch` for every candidate
    (half-width ``half[c]``, output ``u0[c]`` before the first input) over the inputs ``x``:
    ``(C, K)``, compiled; ``None`` when the numpy path must run."""
    lib = active_library()
    args = None if lib is None else _rows(x, half, u0)
    if args is None:
        return None
    x, half, u0 = args
    C, K = half.size, x.size
    out = np.empty((C, K))
    lib.hb_backlash_rows(C, K, x, half, u0, np.empty(C), out)
    return out


def stiction_rows(
    x: np.ndarray,
    x0: float,
    S: np.ndarray,
    J: np.ndarray,
    h: np.ndarray,
    d: np.ndarray,
    x_ss: np.ndarray,
    u: np.ndarray,
) -> np.ndarray | None:
    """The stiction rules of :func:`hbench.diagnose.core.stiction_batch` for every candidate
    (band ``S``, jump ``J``, half-width ``h = (S - J) / 2``; at the start stuck, direction ``d``,
    stick input ``x_ss``, output ``u``; previous input ``x0``) over the inputs ``x``:
    ``(C, K)``, compiled; ``None`` when the numpy path must run."""
    lib = active_library()
    args = None if lib is None else _rows(x, S, J, h, d, x_ss, u)
    if args is None:
        return None
    x, S, J, h, d, x_ss, u = args
    C, K = S.size, x.size
    out = np.empty((C, K))
    lib.hb_stiction_rows(C, K, x, float(x0), S, J, h, d, x_ss, u, np.empty(C, np.uint8), out)
    return out
