"""Numba kernels of the interface geometry (closest points, cut-cell fractions).

Each kernel does, per point or per cell, the floating-point operations of the
vectorised numpy expression it replaces, in the same order, so its results
are bit-identical to it (no fast-math: no reassociation, no fused
multiply-add); only the loops are compiled.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["closest_points_kernel", "positive_fraction_kernel"]


@njit(cache=True, error_model="numpy")
def closest_points_kernel(points, segs):  # pragma: no cover - compiled
    """The closest point of the segments ``(m, 2, 2)`` to each point ``(n, 2)``: ``(n, 2)``.

    Per point and segment: ``s = clip(((p - a).(b - a)) / max(|b - a|^2, 1e-300), 0, 1)``,
    ``c = a + s (b - a)``; the segment of the smallest ``|p - c|^2`` wins (the
    first of equal ones, as ``argmin``).
    """
    n = points.shape[0]
    m = segs.shape[0]
    ax = np.empty(m)
    ay = np.empty(m)
    bx = np.empty(m)
    by = np.empty(m)
    ab2 = np.empty(m)
    for j in range(m):
        ax[j] = segs[j, 0, 0]
        ay[j] = segs[j, 0, 1]
        bx[j] = segs[j, 1, 0] - ax[j]
        by[j] = segs[j, 1, 1] - ay[j]
        ab2[j] = max(bx[j] * bx[j] + by[j] * by[j], 1e-300)
    out = np.empty((n, 2))
    if m == 0:
        out[:] = np.nan
        return out
    d2 = np.empty(m)
    for i in range(n):
        px = points[i, 0]
        py = points[i, 1]
        for j in range(m):  # branch-free: vectorised by LLVM
            s = ((px - ax[j]) * bx[j] + (py - ay[j]) * by[j]) / ab2[j]
            s = min(max(s, 0.0), 1.0)
            dx = px - (ax[j] + s * bx[j])
            dy = py - (ay[j] + s * by[j])
            d2[j] = dx * dx + dy * dy
        k = 0
        for j in range(1, m):
            if d2[j] < d2[k]:
                k = j
        s = ((px - ax[k]) * bx[k] + (py - ay[k]) * by[k]) / ab2[k]
        s = min(max(s, 0.0), 1.0)
        out[i, 0] = ax[k] + s * bx[k]
        out[i, 1] = ay[k] + s * by[k]
    return out


@njit(cache=True, error_model="numpy")
def positive_fraction_kernel(vals):  # pragma: no cover - compiled
    """Area fraction of each triangle ``(n, 3)`` where the linear interpolant is > 0.

    The odd vertex ``a`` (the only positive or the only negative one; zeros
    count as ``1e-300``) and the others ``b``, ``c`` (sorted):
    ``f = clip(a^2 / ((a - b)(a - c)), 0, 1)`` (non-finite: 0 or the nearest
    finite), ``f`` with one positive vertex, ``1 - f`` with two.
    """
    n = vals.shape[0]
    out = np.empty(n)
    big = np.finfo(np.float64).max
    for i in range(n):
        v0 = vals[i, 0]
        v1 = vals[i, 1]
        v2 = vals[i, 2]
        if v0 == 0.0:
            v0 = 1e-300
        if v1 == 0.0:
            v1 = 1e-300
        if v2 == 0.0:
            v2 = 1e-300
        npos = (v0 > 0) + (v1 > 0) + (v2 > 0)
        if npos == 0:
            out[i] = 0.0
            continue
        if npos == 3:
            out[i] = 1.0
            continue
        # sort the three values (s0 <= s1 <= s2)
        if v0 > v1:
            v0, v1 = v1, v0
        if v1 > v2:
            v1, v2 = v2, v1
        if v0 > v1:
            v0, v1 = v1, v0
        if npos == 1:
            a, b, c = v2, v0, v1
        else:
            a, b, c = v0, v1, v2
        f = a * a / ((a - b) * (a - c))
        if np.isnan(f):
            f = 0.0
        elif f > big:
            f = big
        elif f < -big:
            f = -big
        if f < 0.0:
            f = 0.0
        elif f > 1.0:
            f = 1.0
        out[i] = f if npos == 1 else 1.0 - f
    return out
