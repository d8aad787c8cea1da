"""Small linear algebra that never calls BLAS or LAPACK, so a run gives the same doubles on every CPU.

numpy's ``@``/``np.dot``/``np.linalg`` and scipy's spline and ODE solvers hand
their products and factorisations to OpenBLAS, which picks a kernel for the CPU
it runs on (``SkylakeX`` with AVX-512, ``Haswell``/``Zen`` with AVX2, ...).
Those kernels sum in different orders and fuse multiply-adds differently, so
the same run differed in the 13th digit between an AVX-512 and an AVX2 machine.
Pinning the kernel (``OPENBLAS_CORETYPE``) would have to happen before numpy
loads in every process, including Dask workers and users' scripts that we do
not start; so the per-run numerics avoid BLAS instead (docs/reproduction.md,
"Reproducibility").  Every operation here is a fixed sequence of IEEE-754
scalar operations on Python floats: exactly rounded, in a fixed order,
identical on any x86-64 CPU.

The sizes are tiny (2x2 input matrices, a collocation system of a few tens of
anchors), so speed is not a concern; ``bench/bench_blas_free.py`` measures it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numba
import numpy as np
import numpy.typing as npt

from vesselbot_ros.errors import ModelInputError

if TYPE_CHECKING:  # scipy.interpolate takes 0.7 s to import; only the stages that build splines pay it
    from scipy.interpolate import BSpline

__all__ = [
    "Mat2",
    "mat_inverse",
    "mat_apply",
    "mat2",
    "mat2_inverse",
    "mat2_apply",
    "hypot_axes",
    "solve",
    "convolve_valid",
    "interp_spline",
    "interp_spline_fitpack",
    "hypot2",
    "hypot3",
    "dot3",
    "sym3_least_eigvec",
    "solve3",
]

#: A 2x2 matrix as four Python floats ``(a, b, c, d)`` = ``[[a, b], [c, d]]``.
Mat2 = tuple[float, float, float, float]


def mat2(m: npt.ArrayLike) -> Mat2:
    """``[[a, b], [c, d]]`` (any (2, 2) array-like) as a :data:`Mat2`.

    Raises:
        ModelInputError: if ``m`` is not a finite (2, 2) matrix.
    """
    a = np.asarray(m, dtype=np.float64)
    if a.shape != (2, 2) or not np.all(np.isfinite(a)):
        raise ModelInputError(f"expected a finite (2, 2) matrix, got {m!r}")
    return (float(a[0, 0]), float(a[0, 1]), float(a[1, 0]), float(a[1, 1]))


def mat2_inverse(m: Mat2) -> Mat2:
    """Inverse of a 2x2 matrix by the adjugate formula.

    Raises:
        ModelInputError: if ``m`` is singular (determinant below 1e-12 of its scale squared).
    """
    a, b, c, d = m
    det = a * d - b * c
    scale = max(1.0, abs(a), abs(b), abs(c), abs(d))
    if not abs(det) >= 1e-12 * scale * scale:
        raise ModelInputError(f"matrix must be invertible, got {[[a, b], [c, d]]}")
    return (d / det, -b / det, -c / det, a / det)


def mat2_apply(m: Mat2, x0: float, x1: float) -> tuple[float, float]:
    """``m @ (x0, x1)`` as two floats, each a product sum in a fixed order."""
    a, b, c, d = m
    return (a * x0 + b * x1, c * x0 + d * x1)


def mat_inverse(m: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """Inverse of a (d, d) matrix without BLAS: :func:`mat2_inverse` for d = 2, the reciprocals of a diagonal one,
    else :func:`solve` against the identity.

    Raises:
        ModelInputError: a non-square, non-finite or singular matrix.
    """
    a = np.asarray(m, dtype=np.float64)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or not np.all(np.isfinite(a)):
        raise ModelInputError(f"expected a finite square matrix, got {m!r}")
    if a.shape == (2, 2):
        return np.array(mat2_inverse(mat2(a))).reshape(2, 2)
    diag = np.diag(a)
    if np.array_equal(a, np.diag(diag)):
        if not np.all(diag != 0.0):
            raise ModelInputError(f"matrix must be invertible, got {a.tolist()}")
        return np.diag(1.0 / diag)
    return np.asarray(solve(a, np.eye(a.shape[0])), dtype=np.float64)


def mat_apply(m: npt.NDArray[np.float64], x: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``m @ x`` for a (d, d) matrix, each row a product sum in a fixed order (:func:`mat2_apply` for d = 2)."""
    v = np.asarray(x, dtype=np.float64)
    out = np.empty(m.shape[0])
    for i in range(m.shape[0]):
        acc = float(m[i, 0]) * float(v[0])
        for j in range(1, m.shape[1]):
            acc = acc + float(m[i, j]) * float(v[j])
        out[i] = acc
    return out


def solve(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.float64] | npt.NDArray[np.complex128]:
    """Solve ``a x = b`` by Gaussian elimination with partial pivoting, in Python scalars.

    Args:
        a: (n, n) real or complex matrix.
        b: (n,) or (n, m) right-hand side(s).

    Returns:
        ``x`` with the shape of ``b``.

    Raises:
        ModelInputError: on a non-square, non-finite or singular system.
    """
    am = np.asarray(a)
    bm = np.asarray(b)
    n = am.shape[0] if am.ndim == 2 else -1
    if am.ndim != 2 or am.shape != (n, n) or bm.shape[:1] != (n,) or bm.ndim > 2:
        raise ModelInputError(f"solve needs an (n, n) matrix and (n,) or (n, m) right-hand side, got {am.shape}, {bm.shape}")
    if not (np.all(np.isfinite(am)) and np.all(np.isfinite(bm))):
        raise ModelInputError("solve needs a finite system")
    cplx = np.iscomplexobj(am) or np.iscomplexobj(bm)
    conv = complex if cplx else float
    rows = [[conv(v) for v in row] for row in am.tolist()]
    rhs = [[conv(v) for v in (r if isinstance(r, list) else [r])] for r in bm.tolist()]
    m = len(rhs[0])
    for col in range(n):
        piv = max(range(col, n), key=lambda r: abs(rows[r][col]))
        if rows[piv][col] == 0.0:  # as LAPACK's getrf: only an exactly zero pivot is singular
            raise ModelInputError(f"solve: singular matrix (zero pivot in column {col})")
        if piv != col:
            rows[col], rows[piv] = rows[piv], rows[col]
            rhs[col], rhs[piv] = rhs[piv], rhs[col]
        pr, prhs, p = rows[col], rhs[col], rows[col][col]
        for r in range(col + 1, n):
            f = rows[r][col] / p
            if f == 0.0:
                continue
            row = rows[r]
            for j in range(col, n):
                row[j] = row[j] - f * pr[j]
            rr = rhs[r]
            for j in range(m):
                rr[j] = rr[j] - f * prhs[j]
    x = [[conv(0.0)] * m for _ in range(n)]
    for i in range(n - 1, -1, -1):
        row = rows[i]
        for j in range(m):
            s = rhs[i][j]
            for c in range(i + 1, n):
                s = s - row[c] * x[c][j]
            x[i][j] = s / row[i]
    out = np.array(x, dtype=np.complex128) if cplx else np.array(x, dtype=np.float64)
    return out[:, 0] if bm.ndim == 1 else out


def convolve_valid(x: npt.ArrayLike, w: npt.ArrayLike) -> npt.NDArray[np.float64]:
    """``np.convolve(x, w, mode="valid")`` without BLAS: every output summed in one fixed order.

    numpy's ``convolve`` sums each output with the BLAS ``ddot`` of the
    kernel it loaded, and the AVX-512 and AVX2 kernels sum in different
    orders (the planner's smoothed speeds differed in their last bits).  Here
    each output ``sum_i x[j + i] w[n - 1 - i]`` is its products, each rounded,
    added in the order of OpenBLAS's AVX2 ``ddot``: the first ``n & -16``
    products as sixteen partial sums (product ``i`` into sum ``i % 16``),
    folded as that kernel folds its four 4-wide registers, then the remaining
    products one by one.  For a kernel shorter than 32 (one block: the
    planner's 21 taps) that is exactly what the AVX2 kernel returns, so the
    plans made under it keep their bits; from 32 taps on the AVX2 kernel
    fuses its multiply-adds, and this stays its own fixed, rounded order.

    Args:
        x: (m,) signal, ``m >= n``.
        w: (n,) kernel, ``n >= 1``.

    Returns:
        ``(m - n + 1,)`` outputs.
    """
    xa = np.asarray(x, dtype=np.float64)
    wa = np.asarray(w, dtype=np.float64)
    if xa.ndim != 1 or wa.ndim != 1 or wa.size < 1 or xa.size < wa.size:
        raise ModelInputError(f"convolve_valid needs 1-D x at least as long as a non-empty 1-D w, "
                              f"got {xa.shape}, {wa.shape}")
    n = wa.size
    m = xa.size - n + 1
    wr = wa[::-1]
    prod = [xa[i:i + m] * wr[i] for i in range(n)]  # elementwise: IEEE products, no BLAS
    n1 = n & -16
    if n1:
        lanes = [0.0 + prod[i] for i in range(16)]  # register k = i // 4, lane i % 4 (the AVX2 kernel's layout)
        for b in range(16, n1, 16):
            lanes = [lanes[i] + prod[b + i] for i in range(16)]
        # each register's high half onto its low half, then the registers pairwise, then the two lanes
        half = [[lanes[4 * k] + lanes[4 * k + 2], lanes[4 * k + 1] + lanes[4 * k + 3]] for k in range(4)]
        pair = [(half[0][j] + half[1][j]) + (half[2][j] + half[3][j]) for j in range(2)]
        dot = pair[0] + pair[1]
    else:
        dot = np.zeros(m)
    for i in range(n1, n):
        dot = dot + prod[i]
    return np.asarray(dot, dtype=np.float64)


def _knots(x: npt.NDArray[np.float64], k: int) -> npt.NDArray[np.float64]:
    """The knots :func:`scipy.interpolate.make_interp_spline` uses (natural for k = 3, else its default)."""
    if k == 3:  # natural end conditions: x itself, ends repeated k + 1 times
        return np.r_[(x[0],) * 3, x, (x[-1],) * 3]
    if k == 2:  # scipy's default for even k: knots between the data points
        mid = (x[1:] + x[:-1]) / 2.0
        return np.r_[(x[0],) * 3, mid[1:-1], (x[-1],) * 3]
    if k == 1:
        return np.r_[x[0], x, x[-1]]
    raise ModelInputError(f"interp_spline supports k in 1..3, got {k}")


def interp_spline(x: Sequence[float] | npt.NDArray[np.float64], y: npt.ArrayLike, k: int = 3) -> BSpline:
    """Interpolating B-spline through ``(x, y)``; natural end conditions for ``k = 3``.

    The same spline as ``make_interp_spline(x, y, k, bc_type="natural" if k == 3
    else None)`` (same knots, coefficients equal to rounding), with the
    collocation system solved by :func:`solve` instead of LAPACK.  The
    collocation matrix comes from scipy's own B-spline evaluation (no BLAS).

    Args:
        x: (n,) strictly increasing abscissae; ``n >= k + 1``.
        y: (n,) or (n, d) values.
        k: Degree, 1..3.

    Returns:
        The :class:`scipy.interpolate.BSpline`.
    """
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    if xa.ndim != 1 or xa.size < k + 1 or ya.shape[:1] != xa.shape or not np.all(np.diff(xa) > 0.0):
        raise ModelInputError(f"interp_spline needs >= {k + 1} strictly increasing x and matching y, got {xa!r}")
    t = _knots(xa, k)
    nc = t.size - k - 1
    # deferred: scipy.interpolate takes ~0.5 s to import and every core imports this module; only spline builders pay it
    from scipy.interpolate import BSpline

    eye = BSpline.construct_fast(t, np.eye(nc), k)
    rows = [eye(xa)]
    rhs = [ya.reshape(xa.size, -1)]
    if k == 3:  # natural: second derivative zero at both ends
        rows = [eye(xa[:1], nu=2), *rows, eye(xa[-1:], nu=2)]
        zero = np.zeros((1, rhs[0].shape[1]))
        rhs = [zero, *rhs, zero]
    c = solve(np.vstack(rows), np.vstack(rhs))
    return BSpline.construct_fast(t, np.asarray(c).reshape((nc, *ya.shape[1:])), k)


def interp_spline_fitpack(x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]) -> BSpline:
    """Not-a-knot cubic spline through many points ``(x, y)`` by FITPACK (``splrep``, ``s = 0``).

    FITPACK factorises with Givens rotations in its own Fortran, with no BLAS,
    so the coefficients are the same on every CPU; it also scales linearly
    with the number of points, which the dense :func:`solve` does not.

    Args:
        x: (n,) strictly increasing abscissae, n >= 4.
        y: (n,) values.
    """
    if x.ndim != 1 or x.size < 4 or y.shape != x.shape or not all(math.isfinite(v) for v in y):
        raise ModelInputError("interp_spline_fitpack needs >= 4 points and finite values")
    # deferred: scipy.interpolate takes ~0.5 s to import and every core imports this module; only spline builders pay it
    from scipy.interpolate import BSpline, splrep

    t, c, k = splrep(x, y, k=3, s=0)
    return BSpline.construct_fast(t, c, k)


@numba.njit(cache=True, nogil=True)
def _two_square(x):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    # (hi, lo) with hi = fl(x * x) and hi + lo = x * x exactly (Dekker's product error, no fma)
    hi = x * x
    t = x * 134217729.0  # Veltkamp split, 2**27 + 1
    xh = t - (t - x)
    xl = x - xh
    lo = ((xh * xh - hi) + 2.0 * xh * xl) + xl * xl
    return hi, lo


@numba.njit(cache=True, nogil=True)
def _vector_norm(ax, ay, az):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """CPython's ``vector_norm`` of three finite non-negative coordinates, not all 0 (a 0 adds exactly nothing)."""
    mx = ax if ax > ay else ay
    mx = mx if mx > az else az
    _m, max_e = math.frexp(mx)
    if max_e < -1023:  # subnormal: scale up as CPython does (DBL_MIN)
        dmin = 2.2250738585072014e-308
        return dmin * _vector_norm(ax / dmin, ay / dmin, az / dmin)
    scale = math.ldexp(1.0, -max_e)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    for v in (ax, ay, az):
        v = v * scale
        phi, plo = _two_square(v)
        s = csum + phi
        slo = (csum - s) + phi
        csum = s
        frac1 += plo
        frac2 += slo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2))
    phi, plo = _two_square(h)
    phi = -phi
    plo = -plo
    s = csum + phi
    slo = (csum - s) + phi
    csum = s
    frac1 += plo
    frac2 += slo
    r = csum - 1.0 + (frac1 + frac2)
    h += r / (2.0 * h)
    return h / scale


@numba.njit(cache=True, nogil=True)
def hypot2(x, y):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``math.hypot(x, y)`` of CPython 3.11+, double for double, for compiled code.

    numba's ``math.hypot`` calls the C library's ``hypot``, which gives a
    different double than CPython's own algorithm for about 0.3 % of inputs,
    so a compiled stage that must equal its Python twin calls this instead.
    It transcribes CPython's ``vector_norm``: lossless power-of-two scaling,
    exact squares, Neumaier-compensated sum around 1.0, square root with one
    differential correction (:func:`_vector_norm`, whose third coordinate 0
    adds exactly nothing).  Pinned against ``math.hypot`` by
    ``test/unit/test_blas_free.py``.
    """
    ax = abs(x)
    ay = abs(y)
    if math.isinf(ax) or math.isinf(ay):
        return math.inf
    if math.isnan(ax) or math.isnan(ay):
        return math.nan
    if ax == 0.0 and ay == 0.0:
        return 0.0
    return _vector_norm(ax, ay, 0.0)


@numba.njit(cache=True, nogil=True)
def hypot3(x, y, z):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``math.hypot(x, y, z)`` of CPython 3.11+, double for double, for compiled code (:func:`hypot2`'s algorithm
    over three coordinates).  A zero coordinate adds exactly nothing to its sums: ``hypot3(x, 0, z) == hypot2(x, z)``,
    so a 3-D stage in the plane y = 0 keeps the planar stage's doubles.  Pinned against ``math.hypot`` by
    ``test/unit/test_blas_free.py``."""
    ax = abs(x)
    ay = abs(y)
    az = abs(z)
    if math.isinf(ax) or math.isinf(ay) or math.isinf(az):
        return math.inf
    if math.isnan(ax) or math.isnan(ay) or math.isnan(az):
        return math.nan
    if ax == 0.0 and ay == 0.0 and az == 0.0:
        return 0.0
    return _vector_norm(ax, ay, az)


@numba.njit(cache=True, nogil=True, _nrt=False)  # type: ignore[call-overload]  # no runtime: no reference counts on the views it passes (physics.integrator)
def hypot_axes(v):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The Euclidean norm of a vector of two or three axes, :func:`hypot2` or :func:`hypot3` (the same double for
    ``(x, z)`` as for ``(x, 0, z)``): the norm of a stage that runs on any number of axes."""
    if v.shape[0] == 3:
        return hypot3(v[0], v[1], v[2])
    return hypot2(v[0], v[1])


@numba.njit(cache=True, nogil=True)
def dot3(a, b):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``a . b`` of two 3-vectors, ``(a0 b0 + a1 b1) + a2 b2``, for compiled code.

    numba's ``a @ b`` calls the BLAS ``ddot`` through scipy, whose AVX-512
    kernel fuses multiply-adds where the AVX2 and SSE kernels do not; this
    order is the one those two give, so code they built keeps its bits.
    """
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@numba.njit(cache=True, nogil=True)
def sym3_least_eigvec(m):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """The unit eigenvector of the least eigenvalue of the symmetric 3x3 ``m`` (its upper triangle is read), for
    compiled code, by cyclic Jacobi rotations: pairs (0, 1), (0, 2), (1, 2) in turn, an off-diagonal element
    dropped once below 1e-17 of its diagonal pair (the classical threshold), at most 64 sweeps.

    numba's ``np.linalg.eigh`` calls LAPACK, whose reductions go through the BLAS kernel the CPU picks.  Ties:
    the lowest index.  Sign: the largest component (the first of equals) positive, so it is one vector, not
    either of two.  Returns ``(eigenvalue, (3,) vector)``.
    """
    a = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            a[i, j] = m[min(i, j), max(i, j)]
    v = np.zeros((3, 3))
    for i in range(3):
        v[i, i] = 1.0
    for _sweep in range(64):
        if a[0, 1] == 0.0 and a[0, 2] == 0.0 and a[1, 2] == 0.0:
            break
        for r in range(3):
            p = 0 if r < 2 else 1
            q = 1 if r == 0 else 2
            apq = a[p, q]
            if apq == 0.0:
                continue
            if abs(apq) <= 1e-17 * (abs(a[p, p]) + abs(a[q, q])):
                a[p, q] = 0.0
                a[q, p] = 0.0
                continue
            theta = (a[q, q] - a[p, p]) / (2.0 * apq)
            if abs(theta) > 1e150:
                t = 0.5 / theta
            else:
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
            c = 1.0 / math.sqrt(t * t + 1.0)
            s = t * c
            for k in range(3):  # A <- A J (columns p, q)
                akp = a[k, p]
                akq = a[k, q]
                a[k, p] = c * akp - s * akq
                a[k, q] = s * akp + c * akq
            for k in range(3):  # A <- J^T A (rows p, q)
                apk = a[p, k]
                aqk = a[q, k]
                a[p, k] = c * apk - s * aqk
                a[q, k] = s * apk + c * aqk
            a[p, q] = 0.0
            a[q, p] = 0.0
            for k in range(3):  # V <- V J
                vkp = v[k, p]
                vkq = v[k, q]
                v[k, p] = c * vkp - s * vkq
                v[k, q] = s * vkp + c * vkq
    j = 0
    for i in range(1, 3):
        if a[i, i] < a[j, j]:
            j = i
    out = np.empty(3)
    big = 0
    for i in range(3):
        out[i] = v[i, j]
        if abs(out[i]) > abs(out[big]):
            big = i
    L = math.sqrt(out[0] * out[0] + out[1] * out[1] + out[2] * out[2])
    sg = 1.0 if out[big] >= 0.0 else -1.0
    for i in range(3):
        out[i] = sg * out[i] / L
    return a[j, j], out


@numba.njit(cache=True, nogil=True)
def solve3(a, b):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """``(det a, x)`` with ``a x = b`` for a 3x3 ``a``, for compiled code: Gaussian elimination with partial
    pivoting (the first of equal pivots), as :func:`solve` does in Python; ``x`` is NaN if a pivot is exactly 0.

    numba's ``np.linalg.det`` and ``solve`` call LAPACK's LU, which goes through the CPU's BLAS kernel.
    """
    m = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            m[i, j] = a[i, j]
        m[i, 3] = b[i]
    det = 1.0
    x = np.empty(3)
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(m[r, col]) > abs(m[piv, col]):
                piv = r
        if m[piv, col] == 0.0:
            x[:] = np.nan
            return 0.0, x
        if piv != col:
            det = -det
            for j in range(4):
                tmp = m[col, j]
                m[col, j] = m[piv, j]
                m[piv, j] = tmp
        p = m[col, col]
        det *= p
        for r in range(col + 1, 3):
            f = m[r, col] / p
            if f == 0.0:
                continue
            for j in range(col, 4):
                m[r, j] = m[r, j] - f * m[col, j]
    for i in range(2, -1, -1):
        s = m[i, 3]
        for c in range(i + 1, 3):
            s = s - m[i, c] * x[c]
        x[i] = s / m[i, i]
    return det, x
