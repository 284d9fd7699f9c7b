"""LAPACK / BLAS calls that release the GIL, for the tiles' threads.

SciPy's ``scipy.linalg`` wrappers (f2py) hold the GIL while LAPACK runs, so threads over
tiles (:mod:`terrain.tiled`) ran their Cholesky factors and triangular solves one at a
time: measured on 2 cores, ``solve_triangular`` with two threads ran at 0.77-0.9x the
speed of one. SciPy also exports the same routines to Cython (``scipy.linalg.cython_blas`` and
``cython_lapack``, a public, stable interface); calling those function pointers through
:mod:`ctypes` releases the GIL for the call. The arguments are exactly those SciPy's own
wrappers pass (a Fortran-ordered copy for ``dpotrf``, the transposed view for ``dtrsm``),
so the results are the same bits as ``scipy.linalg.cholesky`` and ``solve_triangular``
(tested in tests/test_nogil_lapack.py; SciPy 1.17's ``solve_triangular`` rounds some small
systems differently, within 1e-14, and then only the fallback below differs).
``terrain.linalg.cholesky_jitter`` factors through it, so every Cholesky of the package
releases the GIL.
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
import scipy.linalg.cython_blas as _cython_blas
import scipy.linalg.cython_lapack as _cython_lapack
from scipy.linalg import LinAlgError, cho_solve, cholesky, eigh, solve_triangular

__all__ = ["cho_solve_lower", "cholesky_lower", "solve_lower", "symmetric_eigen"]

_char_p = ctypes.c_char_p
_int_p = ctypes.POINTER(ctypes.c_int)
_dbl_p = ctypes.POINTER(ctypes.c_double)


def _function(module, name: str, *argtypes):
    """A ctypes callable for the Cython-exported routine ``name`` (GIL released in calls),
    or ``None`` where this SciPy does not export it with 32-bit integers (then the SciPy
    wrapper is used, GIL held)."""
    try:
        capsule = module.__pyx_capi__[name]
        get_name = ctypes.pythonapi.PyCapsule_GetName
        get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        signature = get_name(capsule)
        if b"int *" not in signature or b"int64" in signature:
            return None
        get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
        get_pointer.restype = ctypes.c_void_p
        get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        return ctypes.CFUNCTYPE(None, *argtypes)(get_pointer(capsule, signature))
    except (AttributeError, KeyError, TypeError, ValueError):
        return None


@functools.cache
def _dpotrf():
    # dpotrf(uplo, n, a, lda, info)
    return _function(_cython_lapack, "dpotrf", _char_p, _int_p, _dbl_p, _int_p, _int_p)


@functools.cache
def _dtrsm():
    # dtrsm(side, uplo, transa, diag, m, n, alpha, a, lda, b, ldb)
    return _function(
        _cython_blas, "dtrsm", _char_p, _char_p, _char_p, _char_p, _int_p, _int_p, _dbl_p,
        _dbl_p, _int_p, _dbl_p, _int_p,
    )  # fmt: skip


@functools.cache
def _dsyevr():
    # dsyevr(jobz, range, uplo, n, a, lda, vl, vu, il, iu, abstol, m, w, z, ldz, isuppz,
    #        work, lwork, iwork, liwork, info)
    return _function(
        _cython_lapack, "dsyevr", _char_p, _char_p, _char_p, _int_p, _dbl_p, _int_p, _dbl_p,
        _dbl_p, _int_p, _int_p, _dbl_p, _int_p, _dbl_p, _dbl_p, _int_p, _int_p, _dbl_p, _int_p,
        _int_p, _int_p, _int_p,
    )  # fmt: skip


def _ptr(a: np.ndarray):
    return a.ctypes.data_as(_dbl_p)


def cholesky_lower(K: np.ndarray) -> np.ndarray | None:
    """Lower Cholesky factor of a symmetric positive definite ``K``, or ``None`` if it is not.

    Parameters
    ----------
    K : ndarray of shape (n, n)
        Symmetric matrix (only its lower triangle is read); not modified.

    Returns
    -------
    ndarray of shape (n, n) or None
        ``L`` with ``L @ L.T = K`` and zeros above the diagonal (Fortran-ordered), the same
        bits as ``scipy.linalg.cholesky(K, lower=True)``; ``None`` where LAPACK reports that
        ``K`` is not positive definite (the caller adds jitter).
    """
    if _dpotrf() is None:
        try:
            return cholesky(K, lower=True, check_finite=False)
        except LinAlgError:
            return None
    a = np.array(K, dtype=np.float64, order="F", copy=True)
    n = ctypes.c_int(a.shape[0])
    info = ctypes.c_int(0)
    _dpotrf()(b"L", ctypes.byref(n), _ptr(a), ctypes.byref(n), ctypes.byref(info))
    if info.value != 0:
        return None
    # Zero the strict upper triangle in place, as SciPy returns it, through a cached mask
    # (0.29 ms at n = 600, the GIL released; a Python loop over the columns took 0.55 ms
    # holding it, and fancy indexing by np.triu_indices 3.5 ms: docs/terrain.md).
    np.copyto(a, 0.0, where=_strict_upper(a.shape[0]))
    return a


_UPPER: list[np.ndarray] = [np.zeros((0, 0), dtype=bool, order="F")]


def _strict_upper(n: int) -> np.ndarray:
    """Mask of the strict upper triangle, (n, n): a view of one cached mask, grown as needed
    (replaced whole, so a thread never sees a half-built one)."""
    mask = _UPPER[0]
    if mask.shape[0] < n:
        size = max(n, 2 * mask.shape[0])
        mask = np.asfortranarray(np.triu(np.ones((size, size), dtype=bool), 1))
        _UPPER[0] = mask
    return mask[:n, :n]


def solve_lower(L: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``L^{-1} B`` for a lower-triangular ``L``, shape (n, m), overwriting ``B``.

    Parameters
    ----------
    L : ndarray of shape (n, n)
        Lower-triangular factor (C- or Fortran-ordered; only its lower triangle is read).
    B : ndarray of shape (n, m)
        Right-hand sides, Fortran-ordered (e.g. ``Ks.T`` of a C-ordered ``Ks``); overwritten.

    Returns
    -------
    ndarray of shape (n, m)
        ``B`` holding the solution, the same bits as ``scipy.linalg.solve_triangular(L, B,
        lower=True)``.
    """
    if not B.flags.f_contiguous or B.dtype != np.float64:
        raise ValueError("solve_lower needs a Fortran-ordered float64 right-hand side")
    if _dtrsm() is None:
        return solve_triangular(L, B, lower=True, check_finite=False, overwrite_b=True)
    n, m = B.shape
    if L.flags.f_contiguous:
        a, uplo, trans = L, b"L", b"N"
    else:  # a C-ordered L read as Fortran is L^T: upper, solved transposed (as SciPy does)
        a, uplo, trans = np.ascontiguousarray(L), b"U", b"T"
    ni, mi = ctypes.c_int(n), ctypes.c_int(m)
    one = ctypes.c_double(1.0)
    _dtrsm()(
        b"L", uplo, trans, b"N", ctypes.byref(ni), ctypes.byref(mi), ctypes.byref(one),
        _ptr(a), ctypes.byref(ni), _ptr(B), ctypes.byref(ni),
    )  # fmt: skip
    return B


def cho_solve_lower(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``K^{-1} b`` from the lower factor ``L`` of ``K``, the GIL released.

    LAPACK's ``dpotrs`` (what ``scipy.linalg.cho_solve((L, True), b)`` calls) is two
    ``dtrsm``: ``L y = b`` and ``L^T x = y``; called here in the same way, so the same bits
    (tests/test_nogil_lapack.py).

    Parameters
    ----------
    L : ndarray of shape (n, n)
        Lower-triangular factor, Fortran-ordered (as :func:`cholesky_lower` returns it).
    b : ndarray of shape (n,) or (n, k)
        Right-hand sides; not modified.
    """
    if _dtrsm() is None or not L.flags.f_contiguous:
        return cho_solve((L, True), b, check_finite=False)
    x = np.array(b, dtype=np.float64, order="F", copy=True)
    B = x.reshape(x.shape[0], -1, order="F")
    ni, ki = ctypes.c_int(B.shape[0]), ctypes.c_int(B.shape[1])
    one = ctypes.c_double(1.0)
    for trans in (b"N", b"T"):
        _dtrsm()(
            b"L", b"L", trans, b"N", ctypes.byref(ni), ctypes.byref(ki), ctypes.byref(one),
            _ptr(L), ctypes.byref(ni), _ptr(B), ctypes.byref(ni),
        )  # fmt: skip
    return x


def symmetric_eigen(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (ascending) and eigenvectors of a symmetric ``A``, the GIL released.

    LAPACK ``dsyevr`` on the lower triangle with the arguments ``scipy.linalg.eigh(A,
    check_finite=False)`` passes (its default driver: all eigenpairs, ``abstol = 0``, the
    optimal workspace from a query), so the same bits (tests/test_nogil_lapack.py). SciPy's
    own wrapper holds the GIL: a tile's 150 x 150 eigendecomposition (``terrain.tiled.
    local_amplitude``) stalled the other tiles' threads for ~4 ms each.

    Parameters
    ----------
    A : ndarray of shape (n, n)
        Symmetric matrix (only its lower triangle is read); not modified.

    Returns
    -------
    w : ndarray of shape (n,)
        Eigenvalues, ascending.
    V : ndarray of shape (n, n)
        Orthonormal eigenvectors in the columns.
    """
    n = A.shape[0]
    if _dsyevr() is None or n == 0:
        return eigh(A, check_finite=False)
    a = np.array(A, dtype=np.float64, order="F", copy=True)
    w = np.empty(n)
    z = np.empty((n, n), order="F")
    isuppz = np.empty(2 * n, dtype=np.intc)
    ni, il, iu, found, info = (ctypes.c_int(v) for v in (n, 1, n, 0, 0))
    vl, vu, abstol = ctypes.c_double(0.0), ctypes.c_double(1.0), ctypes.c_double(0.0)

    def call(work, lwork, iwork, liwork):
        _dsyevr()(
            b"V", b"A", b"L", ctypes.byref(ni), _ptr(a), ctypes.byref(ni), ctypes.byref(vl),
            ctypes.byref(vu), ctypes.byref(il), ctypes.byref(iu), ctypes.byref(abstol),
            ctypes.byref(found), _ptr(w), _ptr(z), ctypes.byref(ni),
            isuppz.ctypes.data_as(_int_p), _ptr(work), ctypes.byref(lwork),
            iwork.ctypes.data_as(_int_p), ctypes.byref(liwork), ctypes.byref(info),
        )  # fmt: skip

    query, iquery = np.empty(1), np.empty(1, dtype=np.intc)
    call(query, ctypes.c_int(-1), iquery, ctypes.c_int(-1))  # workspace query
    lwork, liwork = max(int(query[0]), 26 * n), max(int(iquery[0]), 10 * n)
    call(
        np.empty(lwork), ctypes.c_int(lwork), np.empty(liwork, dtype=np.intc), ctypes.c_int(liwork)
    )
    if info.value != 0:
        return eigh(A, check_finite=False)  # SciPy's own error for what LAPACK refused
    return w, z
