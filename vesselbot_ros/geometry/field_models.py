"""The smooth models of the sampled 3-D wall's model cells: fitted at build time, checked against the standard.

:func:`_model_cells` fits a flagged cell wholly in the lumen the least of up to ``MODELS`` signed straight
round cylinders or planes (k-means on normals and feet, least-eigenvector axes) from the exact query on its
lattice, and keeps it only if it meets the standard on a finer lattice (:func:`_verify_models`).  The rule
and its measurements: docs/vessels.md, "The wall geometry", `field_models`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from vesselbot_ros.blas_free import solve3, sym3_least_eigvec
from vesselbot_ros.geometry.field_lookup import _NO_MODEL, MODEL_REC, MODELS, NODE_STRIDE, _model, _models
from vesselbot_ros.geometry.surface_query import smooth_wall3d

__all__: list[str] = []  # compiled build steps of geometry.field_build only

@numba.njit(cache=True, _nrt=False)  # type: ignore[call-overload]  # _nrt (no runtime) is an option numba's stubs omit
def _beyond(s, band, out_band, margin):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """True if a signed distance (m) lies beyond the band by more than ``margin``: deeper in the lumen than
    ``band`` or farther outside it than ``out_band``."""
    return s > band + margin if s >= 0.0 else -s > out_band + margin


@numba.njit(cache=True)
def _fit_model(qs, ss, ns, lab, c, f32, out, o):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fit ``out[o:o + NODE_STRIDE]`` to the points labelled ``c`` (positions ``qs``, exact s ``ss``, inward normals
    ``ns``): a straight round cylinder (the axis along the least eigenvector of their sum n n^T, through the point
    nearest their normal lines; sigma -1 if that lies ahead along the inward normals -- a lumen's wall seen from
    within -- else +1: a ridge seen from outside; R the mean of their ``rho - sigma s``) or a plane (their mean
    normal), whichever is nearer their distances.  Rounded to float32 if ``f32``.  Returns False if none."""
    npt = 0
    cen = np.zeros(3)
    mm = np.zeros((3, 3))
    nm = np.zeros(3)
    for p in range(qs.shape[0]):
        if lab[p] != c:
            continue
        npt += 1
        for a in range(3):
            cen[a] += qs[p, a]
            nm[a] += ns[p, a]
            for b in range(3):
                mm[a, b] += ns[p, a] * ns[p, b]
    if npt < 2:
        return False
    cen /= npt
    L = math.sqrt((nm ** 2).sum())
    if not (L > 0.0):
        return False
    nm /= L
    best = np.inf
    cand = np.zeros(NODE_STRIDE)
    # the plane
    r0 = 0.0
    for p in range(qs.shape[0]):
        if lab[p] == c:
            r0 += (ss[p] - ((qs[p, 0] - cen[0]) * nm[0] + (qs[p, 1] - cen[1]) * nm[1] + (qs[p, 2] - cen[2]) * nm[2])) / npt
    for a in range(3):
        cand[a] = cen[a]
        cand[3 + a] = nm[a]
    cand[6] = r0
    cand[7] = 0.0
    for tr in range(2):
        if tr == 1:  # the cylinder
            _w, t = sym3_least_eigvec(mm)  # not np.linalg.eigh: LAPACK goes through the CPU's BLAS kernel
            am = np.zeros((3, 3))
            bm = np.zeros(3)
            off = 0.0
            for p in range(qs.shape[0]):
                if lab[p] != c:
                    continue
                for a in range(3):
                    for b in range(3):
                        pr = (1.0 if a == b else 0.0) - ns[p, a] * ns[p, b]
                        am[a, b] += pr
                        bm[a] += pr * qs[p, b]
            for a in range(3):
                for b in range(3):
                    am[a, b] += t[a] * t[b]
                    bm[a] += t[a] * t[b] * cen[b]
            det, pt = solve3(am, bm)  # not np.linalg.det / solve (LAPACK's LU): as above
            if abs(det) < 1e-12 * npt ** 3:
                continue
            for p in range(qs.shape[0]):
                if lab[p] == c:
                    off += (pt[0] - qs[p, 0]) * ns[p, 0] + (pt[1] - qs[p, 1]) * ns[p, 1] + (pt[2] - qs[p, 2]) * ns[p, 2]
            sg = -1.0 if off > 0.0 else 1.0
            rad = 0.0
            for p in range(qs.shape[0]):
                if lab[p] != c:
                    continue
                dv = qs[p] - pt
                al = dv[0] * t[0] + dv[1] * t[1] + dv[2] * t[2]
                rad += (math.sqrt(max((dv ** 2).sum() - al * al, 0.0)) - sg * ss[p]) / npt
            for a in range(3):
                cand[a] = pt[a]
                cand[3 + a] = t[a]
            cand[6] = rad
            cand[7] = sg
        if f32:
            for a in range(NODE_STRIDE):
                cand[a] = float(np.float32(cand[a]))
        err = 0.0
        for p in range(qs.shape[0]):
            if lab[p] == c:
                ms, _x, _y, _z, _r = _model(qs[p, 0], qs[p, 1], qs[p, 2], cand, 0)
                err = max(err, abs(ms - ss[p]))
        if err < best:
            best = err
            for a in range(NODE_STRIDE):
                out[o + a] = cand[a]
    return best < np.inf


@numba.njit(cache=True)
def _kmeans(vec, k, lab):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Label the rows of ``vec`` (n, 3) with k clusters (farthest-point start, Lloyd's steps); False if one empties."""
    n = vec.shape[0]
    cen = np.zeros((k, 3))
    mean = np.zeros(3)
    for p in range(n):
        mean += vec[p] / n
    dmin = np.full(n, np.inf)
    ref = mean.copy()
    for c in range(k):
        far = -1.0
        arg = 0
        for p in range(n):
            dd = ((vec[p] - ref) ** 2).sum()
            if c > 0:
                dmin[p] = min(dmin[p], dd)
                dd = dmin[p]
            if dd > far:
                far = dd
                arg = p
        cen[c] = vec[arg]
        ref = vec[arg].copy()
        if c == 0:
            for p in range(n):
                dmin[p] = ((vec[p] - ref) ** 2).sum()
    for _it in range(12):
        for p in range(n):
            bd = np.inf
            for c in range(k):
                dd = ((vec[p] - cen[c]) ** 2).sum()
                if dd < bd:
                    bd = dd
                    lab[p] = c
        cnt = np.zeros(k)
        cen[:] = 0.0
        for p in range(n):
            cnt[lab[p]] += 1.0
            cen[lab[p]] += vec[p]
        for c in range(k):
            if cnt[c] == 0.0:
                return False
            cen[c] /= cnt[c]
    return True


@numba.njit(cache=True)
def _check_models(rec, o, qs, ss, ns, use, tol_s, cos_tol, axis_m):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether the model cell ``rec[o:]`` answers within the tolerances at the points ``use`` (the normal not
    tested within ``axis_m`` of the attaining model's axis)."""
    for p in range(qs.shape[0]):
        if not use[p]:
            continue
        ms, mx, my, mz, rho = _models(qs[p, 0], qs[p, 1], qs[p, 2], rec, o)
        if abs(ms - ss[p]) > tol_s or (rho > axis_m and mx * ns[p, 0] + my * ns[p, 1] + mz * ns[p, 2] < cos_tol):
            return False
    return True


@numba.njit(cache=True, parallel=True)
def _model_cells(head, cells, nmax, lat, vlat, band, out_band, tol_s, cos_tol, cos_std, axis_m, f32, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Fit each cell of ``cells`` (m, 3) ``(i, j, k)`` the least of 1 .. ``nmax`` models (docs/vessels.md) from the
    exact query on its lattice of ``lat``^3 points (spacing h / (lat - 1): its corners, the 19 test points and
    the sub-cell centres among them for lat = 5), and test it there (the points within the band or h beyond it).
    Kept only if it meets the standard on the finer lattice of ``vlat``^3 points too (:func:`_verify_models`).
    Returns (records (m, MODEL_REC) float64, models used (m,) int64: 0 failed)."""
    h = head[3]
    m = cells.shape[0]
    rec = np.zeros((m, MODEL_REC))
    used = np.zeros(m, dtype=np.int64)
    npt = lat * lat * lat
    for e in numba.prange(m):
        qs = np.empty((npt, 3))
        ss = np.empty(npt)
        ns = np.empty((npt, 3))
        ft = np.empty((npt, 3))
        use = np.zeros(npt, dtype=np.bool_)
        lab = np.zeros(npt, dtype=np.int64)
        for p in range(npt):
            a = p % lat
            b = (p // lat) % lat
            c = p // (lat * lat)
            qs[p, 0] = head[0] + (cells[e, 0] + a / (lat - 1)) * h
            qs[p, 1] = head[1] + (cells[e, 1] + b / (lat - 1)) * h
            qs[p, 2] = head[2] + (cells[e, 2] + c / (lat - 1)) * h
            s, gx, gy, gz = smooth_wall3d(qs[p, 0], qs[p, 1], qs[p, 2], d, pbox, pstart, grid, nodes, index)
            ss[p] = s
            ns[p, 0] = gx
            ns[p, 1] = gy
            ns[p, 2] = gz
            ft[p, 0] = qs[p, 0] - s * gx
            ft[p, 1] = qs[p, 1] - s * gy
            ft[p, 2] = qs[p, 2] - s * gz
            use[p] = not _beyond(s, band, out_band, h)
        r = rec[e]
        done = False
        for k in range(1, nmax + 1):
            for how in range(2 if k > 1 else 1):
                if k > 1 and not _kmeans(ns if how == 0 else ft, k, lab):
                    continue
                if k == 1:
                    lab[:] = 0
                for _it in range(3):  # fit, then give each point to the model nearest its s and normal
                    ok = True
                    for c in range(MODELS):
                        r[c * NODE_STRIDE + 7] = _NO_MODEL
                    for c in range(k):
                        ok = ok and _fit_model(qs, ss, ns, lab, c, f32, r, c * NODE_STRIDE)
                    if not ok:
                        break
                    if _check_models(r, 0, qs, ss, ns, use, tol_s, cos_tol, axis_m):
                        done = True
                        break
                    if k == 1:
                        break
                    for p in range(npt):
                        bd = np.inf
                        for c in range(k):
                            ms, mx, my, mz, _rho = _model(qs[p, 0], qs[p, 1], qs[p, 2], r, c * NODE_STRIDE)
                            dd = abs(ms - ss[p]) / tol_s + (1.0 - (mx * ns[p, 0] + my * ns[p, 1] + mz * ns[p, 2])) / (1.0 - cos_tol)
                            if dd < bd:
                                bd = dd
                                lab[p] = c
                if done:
                    break
            if done:
                used[e] = k
                break
        if used[e] > 0 and not _verify_models(r, head, cells[e], vlat, band, out_band, tol_s, cos_std, axis_m, d, pbox, pstart,
                                               grid, nodes, index):
            used[e] = 0
    return rec, used


@numba.njit(cache=True)
def _verify_models(r, head, cell, lat, band, out_band, tol_s, cos_std, axis_m, d, pbox, pstart, grid, nodes, index):  # type: ignore[no-untyped-def]  # numba kernel: argument types are inferred at compile time
    """Whether the model cell ``r`` meets the standard on the cell's finer lattice of ``lat``^3 points: the distance
    within ``tol_s`` and the normal within ``cos_std`` of the exact query's, but where the attaining model's axis is
    within ``axis_m`` and the exact normal turns by more than 8 deg to a lattice neighbour (h / (lat - 1) away:
    more than 3 deg within 5 um at h = 0.1 mm, lat = 9 -- undefined to the standard)."""
    h = head[3]
    n = lat * lat * lat
    es = np.empty(n)
    en = np.empty((n, 3))
    for p in range(n):
        x = head[0] + (cell[0] + (p % lat) / (lat - 1)) * h
        y = head[1] + (cell[1] + ((p // lat) % lat) / (lat - 1)) * h
        z = head[2] + (cell[2] + (p // (lat * lat)) / (lat - 1)) * h
        s, gx, gy, gz = smooth_wall3d(x, y, z, d, pbox, pstart, grid, nodes, index)
        es[p] = s
        en[p, 0] = gx
        en[p, 1] = gy
        en[p, 2] = gz
    cos_ill = math.cos(math.radians(8.0))
    for p in range(n):
        if _beyond(es[p], band, out_band, h):
            continue
        a = p % lat
        b = (p // lat) % lat
        c = p // (lat * lat)
        x = head[0] + (cell[0] + a / (lat - 1)) * h
        y = head[1] + (cell[1] + b / (lat - 1)) * h
        z = head[2] + (cell[2] + c / (lat - 1)) * h
        ms, mx, my, mz, rho = _models(x, y, z, r, 0)
        if abs(ms - es[p]) > tol_s:
            return False
        if mx * en[p, 0] + my * en[p, 1] + mz * en[p, 2] >= cos_std:
            continue
        if rho > axis_m:
            return False
        ill = False
        for nb in range(6):
            da = (1 if nb == 0 else -1 if nb == 1 else 0)
            db = (1 if nb == 2 else -1 if nb == 3 else 0)
            dc = (1 if nb == 4 else -1 if nb == 5 else 0)
            if 0 <= a + da < lat and 0 <= b + db < lat and 0 <= c + dc < lat:
                o = ((c + dc) * lat + b + db) * lat + a + da
                if en[o, 0] * en[p, 0] + en[o, 1] * en[p, 1] + en[o, 2] * en[p, 2] < cos_ill:
                    ill = True
        if not ill:
            return False
    return True
