"""Numba kernels of the interface geometry.

Closest points on segments, cut-cell fractions, distances to the nearest segment
(bucketed), point-centre pairs within a radius, and the per-segment circle fits of
the curvature (:mod:`pfem2x.physics.flow.curvature`). Each kernel does, per point,
pair or cell, the floating-point operations of the vectorised numpy expression it
replaced, in the same order (sums in the order ``numpy.bincount`` takes them), so
its results are bit-identical to it (no fast-math: no reassociation, no fused
multiply-add); only the loops are compiled.
"""

from __future__ import annotations

import numpy as np

from pfem2x.aot import njit
from pfem2x.particles._kernels import counting_sort

__all__ = [
    "cell_velocity_kernel",
    "circle_distance_kernel",
    "circle_fit_equations",
    "closest_pairs_within_kernel",
    "closest_points_kernel",
    "cut_segments_kernel",
    "mark_mixed_cells",
    "pairs_within_kernel",
    "particle_fraction_kernel",
    "positive_fraction_kernel",
    "segment_distance_kernel",
]


@njit(cache=True, error_model="numpy")
def _segment_arrays(segs):  # pragma: no cover - compiled
    """Segments ``(m, 2, 2)``: starts ``a``, directions ``b - a``, ``max(|b - a|^2, 1e-300)``."""
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
    return ax, ay, bx, by, ab2


@njit(cache=True, error_model="numpy")
def _circle_distance(s, eta, A, B, D):  # pragma: no cover - compiled
    r"""Signed distance to the circle :math:`\eta = A(s^2 + \eta^2) + Bs + D` and its derivatives.

    :math:`d = 2F/(\sqrt{1 + B^2 - 4AD} + |\nabla F|)`, :math:`F = \eta - A(s^2 + \eta^2) - Bs
    - D`: exact for a circle (and for the line :math:`A = 0`), positive on the side of
    :math:`+\eta`. Returns ``d`` and :math:`\partial d/\partial(A, B, D)` (scalars).
    """
    q = s * s + eta * eta
    F = eta - A * q - B * s - D
    t = 1.0 + B * B - 4.0 * A * D
    if t < 1e-300:  # (a NaN stays NaN)
        t = 1e-300
    den = np.sqrt(t)
    gx = -2.0 * A * s - B
    gy = 1.0 - 2.0 * A * eta
    G = np.sqrt(gx * gx + gy * gy)
    S = den + G
    d = 2.0 * F / S
    dA = (-2.0 * q - d * (-2.0 * D / den - 2.0 * (s * gx + eta * gy) / G)) / S
    dB = (-2.0 * s - d * (B / den - gx / G)) / S
    dD = (-2.0 + d * 2.0 * A / den) / S
    return d, dA, dB, dD


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


@njit(cache=True, error_model="numpy")
def _nearest_segment(points, segs, cap, projected):  # pragma: no cover - compiled
    """The nearest segment ``(m, 2, 2)`` to each point ``(n, 2)``: ``|d|^2`` and index ``(n,)``.

    Per pair, with ``s = clip(((p - a).(b - a)) / max(|b - a|^2, 1e-300), 0, 1)``:
    ``d = (p - a) - s (b - a)``, or with ``projected`` ``d = p - (a + s (b - a))``
    (the closest point first). Of equal ``|d|^2`` the lowest index wins. Only
    segments that can be nearest are measured: the segments are listed in square
    buckets (each in every bucket its bounding box touches) and each point scans
    the buckets in rings around its own, nearest first, until the next ring lies
    farther than the nearest segment found, or than ``cap``. Exact wherever the
    distance is ``<= cap``; beyond ``cap`` ``inf`` (index -1) or a distance ``> cap``.
    """
    n = points.shape[0]
    m = segs.shape[0]
    best2 = np.full(n, np.inf)
    near = np.full(n, -1, dtype=np.int64)
    if m == 0 or n == 0:
        return best2, near
    ax, ay, bx, by, ab2 = _segment_arrays(segs)
    lox = hix = segs[0, 0, 0]
    loy = hiy = segs[0, 0, 1]
    for j in range(m):
        for k in range(2):
            lox = min(lox, segs[j, k, 0])
            hix = max(hix, segs[j, k, 0])
            loy = min(loy, segs[j, k, 1])
            hiy = max(hiy, segs[j, k, 1])
    # bucket side: about one segment per bucket of the box, and not below the segments'
    # mean length (segments along a straight line have a box of no area: buckets much
    # shorter than a segment made a point away from the line scan hundreds of rings),
    # at least cap / 16 (a point within cap scans at most 33 x 33 buckets), at most
    # 4096 buckets a side
    span = max(hix - lox, hiy - loy)
    length = 0.0
    for s in range(m):
        length += np.sqrt(ab2[s])
    b = max(np.sqrt((hix - lox) * (hiy - loy) / m), length / m)
    if cap < np.inf:
        b = max(b, cap / 16.0)
    b = max(b, span / 4096.0)
    if not b > 0.0:
        b = 1.0
    nbx = min(int((hix - lox) / b) + 1, 4097)
    nby = min(int((hiy - loy) / b) + 1, 4097)
    # the buckets' segment lists (CSR): every bucket of a segment's bounding box
    i0 = np.empty(m, dtype=np.int64)
    i1 = np.empty(m, dtype=np.int64)
    j0 = np.empty(m, dtype=np.int64)
    j1 = np.empty(m, dtype=np.int64)
    ptr = np.zeros(nbx * nby + 1, dtype=np.int64)
    for s in range(m):
        i0[s] = min(int((min(ax[s], ax[s] + bx[s]) - lox) / b), nbx - 1)
        i1[s] = min(int((max(ax[s], ax[s] + bx[s]) - lox) / b), nbx - 1)
        j0[s] = min(int((min(ay[s], ay[s] + by[s]) - loy) / b), nby - 1)
        j1[s] = min(int((max(ay[s], ay[s] + by[s]) - loy) / b), nby - 1)
        for i in range(i0[s], i1[s] + 1):
            for j in range(j0[s], j1[s] + 1):
                ptr[i * nby + j + 1] += 1
    for k in range(nbx * nby):
        ptr[k + 1] += ptr[k]
    fill = ptr[:-1].copy()
    lst = np.empty(ptr[-1], dtype=np.int64)
    for s in range(m):
        for i in range(i0[s], i1[s] + 1):
            for j in range(j0[s], j1[s] + 1):
                lst[fill[i * nby + j]] = s
                fill[i * nby + j] += 1
    for q in range(n):
        px = points[q, 0]
        py = points[q, 1]
        # outside the box by more than cap: no segment within cap
        if max(lox - px, 0.0, px - hix) > cap or max(loy - py, 0.0, py - hiy) > cap:
            continue
        ci = min(max(int(np.floor((px - lox) / b)), 0), nbx - 1)
        cj = min(max(int(np.floor((py - loy) / b)), 0), nby - 1)
        best = np.inf
        bs = -1
        r = 0
        while True:
            for i in range(max(ci - r, 0), min(ci + r, nbx - 1) + 1):
                if i == ci - r or i == ci + r:  # the ring's first and last column: all of it
                    ja, jb, jd = max(cj - r, 0), min(cj + r, nby - 1), 1
                else:  # the columns between: the ring's two ends only
                    ja, jb, jd = cj - r, cj + r, max(2 * r, 1)
                for j in range(ja, jb + 1, jd):
                    if j < 0 or j >= nby:
                        continue
                    for k in range(ptr[i * nby + j], ptr[i * nby + j + 1]):
                        s = lst[k]
                        apx = px - ax[s]
                        apy = py - ay[s]
                        t = (apx * bx[s] + apy * by[s]) / ab2[s]
                        t = min(max(t, 0.0), 1.0)
                        if projected:
                            dx = px - (ax[s] + t * bx[s])
                            dy = py - (ay[s] + t * by[s])
                        else:
                            dx = apx - t * bx[s]
                            dy = apy - t * by[s]
                        d2 = dx * dx + dy * dy
                        if d2 < best or (d2 == best and s < bs):
                            best = d2
                            bs = s
            # the buckets not scanned yet are at least `low` away from the point (the
            # margin: a tie there, computed with other round-off, is still scanned)
            low = np.inf
            if ci + r + 1 < nbx:
                low = min(low, max(lox + (ci + r + 1) * b - px, 0.0))
            if ci - r - 1 >= 0:
                low = min(low, max(px - (lox + (ci - r) * b), 0.0))
            if cj + r + 1 < nby:
                low = min(low, max(loy + (cj + r + 1) * b - py, 0.0))
            if cj - r - 1 >= 0:
                low = min(low, max(py - (loy + (cj - r) * b), 0.0))
            if low == np.inf or low * low > best * (1.0 + 1e-9) or low > cap:
                break
            r += 1
        best2[q] = best
        near[q] = bs
    return best2, near


@njit(cache=True, error_model="numpy")
def segment_distance_kernel(points, segs, cap):  # pragma: no cover - compiled
    """Distance ``(n,)`` of each point ``(n, 2)`` to the nearest segment ``(m, 2, 2)``.

    :func:`_nearest_segment`'s ``sqrt(|(p - a) - s (b - a)|^2)``: exact wherever it is
    ``<= cap``; beyond ``cap`` it is ``inf`` or a distance ``> cap`` (``cap = inf``:
    exact everywhere).
    """
    return np.sqrt(_nearest_segment(points, segs, cap, False)[0])


@njit(cache=True, error_model="numpy")
def closest_points_kernel(points, segs):  # pragma: no cover - compiled
    """The closest point of the segments ``(m, 2, 2)`` to each point ``(n, 2)``: ``(n, 2)``.

    The segment of the smallest ``|p - c|^2``, ``c = a + s (b - a)`` with
    ``s = clip(((p - a).(b - a)) / max(|b - a|^2, 1e-300), 0, 1)``, wins (the lowest
    index of equal ones; :func:`_nearest_segment`), and its ``c`` is returned; NaN
    without segments.
    """
    n = points.shape[0]
    out = np.empty((n, 2))
    if segs.shape[0] == 0:
        out[:] = np.nan
        return out
    ax, ay, bx, by, ab2 = _segment_arrays(segs)
    k_of = _nearest_segment(points, segs, np.inf, True)[1]
    for i in range(n):
        k = k_of[i]
        s = ((points[i, 0] - ax[k]) * bx[k] + (points[i, 1] - ay[k]) * by[k]) / ab2[k]
        s = min(max(s, 0.0), 1.0)
        out[i, 0] = ax[k] + s * bx[k]
        out[i, 1] = ay[k] + s * by[k]
    return out


@njit(cache=True, error_model="numpy")
def pairs_within_kernel(centres, points, radius):  # pragma: no cover - compiled
    """Index pairs ``(centre, point)`` closer than ``radius``: two ``(k,)`` arrays.

    Buckets of side ``radius`` from the common lower corner ``lo``: a point in
    bucket ``floor((x - lo) / radius)``; each centre is paired with the points of
    the 3 x 3 buckets around its own, whose squared distance ``dx^2 + dy^2`` is
    ``< radius^2``. The pairs come in the order of the numpy expression this
    replaces: by bucket offset (dx, then dy, each -1, 0, 1), then centre, then
    point index.
    """
    nc = centres.shape[0]
    npt = points.shape[0]
    lo0 = min(centres[:, 0].min(), points[:, 0].min())
    lo1 = min(centres[:, 1].min(), points[:, 1].min())
    pb0 = np.empty(npt, dtype=np.int64)
    pb1 = np.empty(npt, dtype=np.int64)
    cb0 = np.empty(nc, dtype=np.int64)
    cb1 = np.empty(nc, dtype=np.int64)
    m0 = 0
    m1 = 0
    for i in range(npt):
        pb0[i] = np.int64(np.floor((points[i, 0] - lo0) / radius))
        pb1[i] = np.int64(np.floor((points[i, 1] - lo1) / radius))
        m0 = max(m0, pb0[i])
        m1 = max(m1, pb1[i])
    for i in range(nc):
        cb0[i] = np.int64(np.floor((centres[i, 0] - lo0) / radius))
        cb1[i] = np.int64(np.floor((centres[i, 1] - lo1) / radius))
        m0 = max(m0, cb0[i])
        m1 = max(m1, cb1[i])
    ny = m1 + 3
    # stable: a bucket's points in index order
    order, ptr = counting_sort((pb0 + 1) * ny + pb1 + 1, (m0 + 3) * ny)
    total = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for c in range(nc):
                k = (cb0[c] + 1 + dx) * ny + cb1[c] + 1 + dy
                total += ptr[k + 1] - ptr[k]
    ci = np.empty(total, dtype=np.int64)
    pi = np.empty(total, dtype=np.int64)
    r2 = radius * radius
    n = 0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for c in range(nc):
                k = (cb0[c] + 1 + dx) * ny + cb1[c] + 1 + dy
                for j in range(ptr[k], ptr[k + 1]):
                    q = order[j]
                    ex = points[q, 0] - centres[c, 0]
                    ey = points[q, 1] - centres[c, 1]
                    if ex * ex + ey * ey < r2:
                        ci[n] = c
                        pi[n] = q
                        n += 1
    return ci[:n].copy(), pi[:n].copy()


@njit(cache=True, error_model="numpy")
def circle_fit_equations(ci, s, eta, w, y, p, m):  # pragma: no cover - compiled
    r"""One Gauss–Newton step's normal equations of the per-segment circle fits.

    Pair ``k`` (segment ``ci[k]``, a sample at ``(s, eta)`` in the segment's frame,
    weight ``w``, value ``y``) against the segment's fit ``p = (lambda, A, B, D)``:
    the signed distance ``d`` to the circle :math:`\eta = A(s^2 + \eta^2) + Bs + D`
    and its derivatives (:func:`_circle_distance`), ``J = (d, lambda dA, lambda dB,
    lambda dD)``; returns ``M (m, 4, 4)`` = sum of ``w J_i J_j`` and ``rhs (m, 4)`` = sum of
    ``w (y - lambda d) J_i`` per segment, summed in pair order (as ``bincount``).
    """
    M = np.zeros((m, 4, 4))
    rhs = np.zeros((m, 4))
    J = np.empty(4)
    for k in range(ci.shape[0]):
        c = ci[k]
        lam = p[c, 0]
        A = p[c, 1]
        B = p[c, 2]
        D = p[c, 3]
        d, dA, dB, dD = _circle_distance(s[k], eta[k], A, B, D)
        J[0] = d
        J[1] = lam * dA
        J[2] = lam * dB
        J[3] = lam * dD
        wk = w[k]
        res = wk * (y[k] - lam * d)
        for i in range(4):
            for j in range(i, 4):
                M[c, i, j] += wk * J[i] * J[j]
            rhs[c, i] += res * J[i]
    for c in range(m):
        for i in range(4):
            for j in range(i + 1, 4):
                M[c, j, i] = M[c, i, j]
    return M, rhs


@njit(cache=True, error_model="numpy")
def closest_pairs_within_kernel(points, segs, radius, tol):  # pragma: no cover - compiled
    """Pairs ``(point, segment)`` within ``tol`` of the point's closest segment: two ``(k,)``.

    Only segments whose midpoint is within ``radius`` of the point (squared distance
    ``< radius^2``, buckets of side ``radius``) count. Distance per pair:
    ``t = clip(((p - a).(b - a)) / max(|b - a|^2, 1e-300), 0, 1)``,
    ``sqrt(|(p - a) - t (b - a)|^2)``. Sorted by point, then segment.
    """
    n = points.shape[0]
    m = segs.shape[0]
    mx = np.empty(m)
    my = np.empty(m)
    lo0 = np.inf
    lo1 = np.inf
    hi0 = -np.inf
    hi1 = -np.inf
    for j in range(m):
        mx[j] = (segs[j, 0, 0] + segs[j, 1, 0]) / 2.0
        my[j] = (segs[j, 0, 1] + segs[j, 1, 1]) / 2.0
        lo0 = min(lo0, mx[j])
        lo1 = min(lo1, my[j])
        hi0 = max(hi0, mx[j])
        hi1 = max(hi1, my[j])
    nbx = int(np.floor((hi0 - lo0) / radius)) + 1
    nby = int(np.floor((hi1 - lo1) / radius)) + 1
    key = np.empty(m, dtype=np.int64)
    for j in range(m):
        key[j] = int(np.floor((mx[j] - lo0) / radius)) * nby + int(np.floor((my[j] - lo1) / radius))
    lst, ptr = counting_sort(key, nbx * nby)
    r2 = radius * radius
    ax, ay, bx, by, ab2 = _segment_arrays(segs)
    cand = np.empty(m, dtype=np.int64)
    dist = np.empty(m)
    out_p = np.empty(0, dtype=np.int64)
    out_s = np.empty(0, dtype=np.int64)
    n_out = 0
    for q in range(n):
        px = points[q, 0]
        py = points[q, 1]
        fi = np.floor((px - lo0) / radius)
        fj = np.floor((py - lo1) / radius)
        if fi < -1.0 or fj < -1.0 or fi > nbx or fj > nby:
            continue
        bi = int(fi)
        bj = int(fj)
        nc = 0
        best = np.inf
        for i in range(max(bi - 1, 0), min(bi + 1, nbx - 1) + 1):
            for j in range(max(bj - 1, 0), min(bj + 1, nby - 1) + 1):
                for k in range(ptr[i * nby + j], ptr[i * nby + j + 1]):
                    sg = lst[k]
                    ex = mx[sg] - px
                    ey = my[sg] - py
                    if not ex * ex + ey * ey < r2:
                        continue
                    apx = px - ax[sg]
                    apy = py - ay[sg]
                    t = (apx * bx[sg] + apy * by[sg]) / ab2[sg]
                    t = min(max(t, 0.0), 1.0)
                    dx = apx - t * bx[sg]
                    dy = apy - t * by[sg]
                    dd = np.sqrt(dx * dx + dy * dy)
                    cand[nc] = sg
                    dist[nc] = dd
                    nc += 1
                    if dd < best:
                        best = dd
        # the pairs within tol of the closest, by segment index (insertion sort: few)
        start = n_out
        for c in range(nc):
            if dist[c] <= best + tol:
                if n_out == len(out_p):
                    grow = max(16, 2 * len(out_p))
                    np_ = np.empty(grow, dtype=np.int64)
                    ns_ = np.empty(grow, dtype=np.int64)
                    np_[:n_out] = out_p[:n_out]
                    ns_[:n_out] = out_s[:n_out]
                    out_p = np_
                    out_s = ns_
                out_p[n_out] = q
                sg = cand[c]
                k = n_out
                while k > start and out_s[k - 1] > sg:
                    out_s[k] = out_s[k - 1]
                    k -= 1
                out_s[k] = sg
                n_out += 1
    return out_p[:n_out].copy(), out_s[:n_out].copy()


@njit(cache=True, error_model="numpy")
def circle_distance_kernel(s, eta, A, B, D):  # pragma: no cover - compiled
    """:func:`_circle_distance`'s ``d`` for arrays ``(n,)`` of points and circles (one each)."""
    out = np.empty(s.shape[0])
    for k in range(s.shape[0]):
        out[k] = _circle_distance(s[k], eta[k], A[k], B[k], D[k])[0]
    return out


@njit(cache=True, error_model="numpy")
def cell_velocity_kernel(u, dofs, gradlam):  # pragma: no cover - compiled
    """Per cell of a P1 velocity: div u, max vertex speed and the two sums of the energy.

    ``u`` ``(nodes, gdim)``, ``dofs`` ``(cells, nv)``, ``gradlam`` ``(cells, nv, gdim)``
    (the barycentric gradients). Returns ``div`` (sum over the components ``j`` of
    the sums over the vertices ``k`` of ``u_kj g_kj``: numpy's einsum order for
    triangles on x86-64), ``speed`` (the largest ``|u_k|``, NaN if any is NaN),
    ``sq`` (``sum_kj u_kj^2`` in that order) and ``tot`` (``sum_j (sum_k u_kj)^2``).
    """
    n, nv = dofs.shape
    gdim = u.shape[1]
    div = np.empty(n)
    speed = np.empty(n)
    sq = np.empty(n)
    tot = np.empty(n)
    for c in range(n):
        d = 0.0
        for j in range(gdim):
            a = 0.0
            for k in range(nv):
                a += u[dofs[c, k], j] * gradlam[c, k, j]
            d += a
        s = 0.0
        smax = 0.0
        for k in range(nv):
            i = dofs[c, k]
            m = 0.0
            for j in range(gdim):
                vv = u[i, j] * u[i, j]
                m += vv
                s += vv
            r = np.sqrt(m)
            if k == 0 or r > smax or r != r:
                smax = r
        t = 0.0
        for j in range(gdim):
            a = u[dofs[c, 0], j]
            for k in range(1, nv):
                a += u[dofs[c, k], j]
            t += a * a
        div[c] = d
        speed[c] = smax
        sq[c] = s
        tot[c] = t
    return div, speed, sq, tot


@njit(cache=True, error_model="numpy")
def cut_segments_kernel(vals, xy):  # pragma: no cover - compiled
    """The zero iso-line's segment in each cut triangle, ``(m, 2, 2)``, in cell order.

    ``vals`` ``(n, 3)`` vertex values, ``xy`` ``(n, 3, 2)`` vertex coordinates; a cell is
    cut where its vertices' signs (``>= 0``) differ. The ends are the crossings of the
    edges (0, 1), (1, 2), (2, 0), the first two that cross in that order, each at
    ``x_i + s (x_j - x_i)`` with ``s = v_i / (v_i - v_j)``.
    """
    n = vals.shape[0]
    cut = np.zeros(n, dtype=np.bool_)
    m = 0
    for c in range(n):
        p0 = vals[c, 0] >= 0.0
        if (vals[c, 1] >= 0.0) != p0 or (vals[c, 2] >= 0.0) != p0:
            cut[c] = True
            m += 1
    out = np.empty((m, 2, 2))
    k = 0
    for c in range(n):
        if not cut[c]:
            continue
        e_out = 0
        for e in range(3):
            i = e
            j = (e + 1) % 3
            vi = vals[c, i]
            vj = vals[c, j]
            if (vi >= 0.0) == (vj >= 0.0):
                continue
            s = vi / (vi - vj)
            out[k, e_out, 0] = xy[c, i, 0] + s * (xy[c, j, 0] - xy[c, i, 0])
            out[k, e_out, 1] = xy[c, i, 1] + s * (xy[c, j, 1] - xy[c, i, 1])
            e_out += 1
            if e_out == 2:
                break
        k += 1
    return out


@njit(cache=True, error_model="numpy")
def mark_mixed_cells(phi, dofmap, mark):  # pragma: no cover - compiled
    """``mark[d] = 1`` at every node of each cell of ``dofmap`` whose nodes' signs of ``phi``
    (``>= 0``) differ; other entries are left as they are."""
    nv = dofmap.shape[1]
    for c in range(dofmap.shape[0]):
        p0 = phi[dofmap[c, 0]] >= 0.0
        mixed = False
        for i in range(1, nv):
            if (phi[dofmap[c, i]] >= 0.0) != p0:
                mixed = True
        if mixed:
            for i in range(nv):
                mark[dofmap[c, i]] = 1.0


@njit(cache=True, error_model="numpy")
def particle_fraction_kernel(cells, phase, n_owned, nodal, dofmap):  # pragma: no cover
    """Each owned cell's mean particle ``phase`` (``numpy.bincount``'s sums, in particle
    order); a cell without particles: the mean of ``nodal`` at its nodes."""
    count = np.zeros(n_owned)
    heavy = np.zeros(n_owned)
    for p in range(cells.shape[0]):
        c = cells[p]
        if c < n_owned:
            count[c] += 1.0
            heavy[c] += phase[p]
    out = np.empty(n_owned)
    nv = dofmap.shape[1]
    for c in range(n_owned):
        if count[c] > 0.0:
            out[c] = heavy[c] / count[c]
        else:
            acc = nodal[dofmap[c, 0]]
            for i in range(1, nv):
                acc += nodal[dofmap[c, i]]
            out[c] = acc / nv
    return out
