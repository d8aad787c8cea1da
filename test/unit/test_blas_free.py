"""BLAS-free linear algebra: same answers as numpy/scipy to rounding, fixed order, clear errors."""

from __future__ import annotations

import math

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.interpolate import make_interp_spline

from vesselbot_ros.blas_free import hypot2, hypot3, interp_spline, interp_spline_fitpack, mat2, mat2_apply, mat2_inverse, solve
from vesselbot_ros.errors import ModelInputError

finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)


@settings(max_examples=200, deadline=None)
@given(st.lists(finite, min_size=4, max_size=4), finite, finite)
def test_mat2_inverse_and_apply_match_numpy(m: list[float], x0: float, x1: float) -> None:
    a = np.array(m).reshape(2, 2)
    det = m[0] * m[3] - m[1] * m[2]
    scale2 = max(1.0, *map(abs, m)) ** 2
    if abs(det) < 1e-12 * scale2:
        with pytest.raises(ModelInputError, match="invertible"):
            mat2_inverse(mat2(a))
        return
    if abs(det) < 1e-6 * scale2:  # ill-conditioned: numpy's answer is no reference
        return
    inv = mat2_inverse(mat2(a))
    np.testing.assert_allclose(np.array(inv).reshape(2, 2), np.linalg.inv(a), rtol=1e-9, atol=1e-9 * np.abs(np.linalg.inv(a)).max())
    got = mat2_apply(mat2(a), x0, x1)
    np.testing.assert_allclose(got, a @ [x0, x1], rtol=1e-12, atol=1e-12 * (abs(x0) + abs(x1)) * np.abs(a).max())


@settings(max_examples=100, deadline=None)
@given(st.integers(1, 8), st.integers(0, 2**32 - 1), st.booleans())
def test_solve_matches_numpy(n: int, seed: int, cplx: bool) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n)) + n * np.eye(n)
    b = rng.normal(size=(n, 2))
    if cplx:
        a = a + 1j * rng.normal(size=(n, n))
    x = solve(a, b)
    np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(solve(a, b[:, 0]), x[:, 0], rtol=0, atol=0)  # one rhs = the same column


def test_solve_pivots_and_refuses_bad_systems() -> None:
    np.testing.assert_allclose(solve([[0.0, 1.0], [1.0, 0.0]], [2.0, 3.0]), [3.0, 2.0], rtol=0, atol=0)
    with pytest.raises(ModelInputError, match="singular"):
        solve([[1.0, 2.0], [2.0, 4.0]], [1.0, 1.0])
    with pytest.raises(ModelInputError, match="finite"):
        solve([[math.nan, 0.0], [0.0, 1.0]], [1.0, 1.0])
    with pytest.raises(ModelInputError, match=r"\(n, n\)"):
        solve(np.ones((2, 3)), [1.0, 1.0])


@pytest.mark.parametrize(("n", "k"), [(2, 1), (3, 2), (4, 3), (9, 3), (25, 3)])
def test_interp_spline_is_make_interp_spline(n: int, k: int) -> None:
    rng = np.random.default_rng(n)
    x = np.cumsum(rng.uniform(0.1, 2.0, n))
    y = rng.normal(size=(n, 2)) * 1e-3
    ours = interp_spline(x, y, k)
    ref = make_interp_spline(x, y, k=k, bc_type="natural" if k == 3 else None)
    np.testing.assert_array_equal(ours.t, ref.t)
    np.testing.assert_allclose(ours.c, ref.c, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(ours(x), y, rtol=0, atol=1e-15)  # interpolates
    if k == 3:  # natural ends, C2 inside
        np.testing.assert_allclose(ours(x[[0, -1]], 2), 0.0, rtol=0, atol=1e-12)


def test_interp_spline_fitpack_is_the_not_a_knot_spline() -> None:
    x = np.linspace(0.0, 2.0, 1001)
    y = np.sin(3.0 * x) + x
    ours = interp_spline_fitpack(x, y)
    ref = make_interp_spline(x, y, k=3)
    xx = np.linspace(0.0, 2.0, 5003)
    np.testing.assert_allclose(ours(xx), ref(xx), rtol=0, atol=1e-14)
    np.testing.assert_allclose(ours(xx, 2), ref(xx, 2), rtol=0, atol=1e-7)
    with pytest.raises(ModelInputError, match="finite"):
        interp_spline_fitpack(x, np.where(x > 1.0, np.nan, y))


@numba.njit(cache=True)
def _hypot2_many(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # type: ignore[type-arg]
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = hypot2(x[i], y[i])
    return out


@numba.njit(cache=True)
def _numba_hypot_many(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # type: ignore[type-arg]
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = math.hypot(x[i], y[i])
    return out


def test_hypot2_is_cpythons_math_hypot_double_for_double() -> None:
    # the trap it exists for: numba's math.hypot (C library) differs from CPython's for ~0.3 % of inputs
    rng = np.random.default_rng(18)
    n = 300_000
    x = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
    y = rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n)
    near = rng.integers(0, 2, n).astype(bool)  # half the pairs of similar size (the coil's gradients)
    y[near] = x[near] * rng.uniform(-3.0, 3.0, np.count_nonzero(near))
    special = [0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1e-310, 1.7976931348623157e308, math.inf, -math.inf, math.nan, 3.0, 4.0]
    xs = np.concatenate([x, np.repeat(special, len(special))])
    ys = np.concatenate([y, np.tile(special, len(special))])
    want = np.array([math.hypot(a, b) for a, b in zip(xs.tolist(), ys.tolist())])
    np.testing.assert_array_equal(_hypot2_many(xs, ys), want)
    assert np.count_nonzero(_numba_hypot_many(x, y) != want[:n]) > 0  # the trap is real on this machine


@numba.njit(cache=True)
def _hypot3_many(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:  # type: ignore[type-arg]
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = hypot3(x[i], y[i], z[i])
    return out


def test_hypot3_is_cpythons_math_hypot_and_hypot2_in_a_plane() -> None:
    """Three coordinates, double for double with CPython (wide and similar magnitudes, specials); with one coordinate
    zero it is hypot2 of the other two, so a 3-D stage in the plane keeps the planar doubles."""
    rng = np.random.default_rng(19)
    n = 200_000
    x, y, z = (rng.standard_normal(n) * 10.0 ** rng.integers(-300, 300, n) for _ in range(3))
    near = rng.integers(0, 2, n).astype(bool)
    y[near] = x[near] * rng.uniform(-3.0, 3.0, np.count_nonzero(near))
    z[near] = x[near] * rng.uniform(-3.0, 3.0, np.count_nonzero(near))
    special = [0.0, -0.0, 5e-324, 2.2250738585072014e-308, 1.7976931348623157e308, math.inf, math.nan, 3.0, 4.0]
    grid = np.array(np.meshgrid(special, special, special)).reshape(3, -1)
    xs, ys, zs = (np.concatenate([a, g]) for a, g in zip((x, y, z), grid))
    want = np.array([math.hypot(a, b, c) for a, b, c in zip(xs.tolist(), ys.tolist(), zs.tolist())])
    np.testing.assert_array_equal(_hypot3_many(xs, ys, zs), want)
    np.testing.assert_array_equal(_hypot3_many(x, np.zeros(n), z), _hypot2_many(x, z))
