r"""Interface curvature from a P1 level set and signed-distance samples (surface tension).

The zero iso-line of a P1 field as oriented segments (:func:`oriented_segments`), their end
points moved onto a quadratic per edge (:func:`refined_segments`), and two curvature
estimates per segment: a least-squares circle through the end points around it
(:func:`segment_curvature`) and a least-squares fit of the exact signed distance of a circle
to the signed-distance samples around it (:func:`distance_curvature`, nodes or particles:
exact for a circle); :func:`smooth_along` averages along the interface and
:func:`smooth_quadratic` fits a quadratic along it, :func:`closest_mean` extends to the
nodes. :func:`region_distance`: the signed distance to a region's boundary sampled below
the mesh size (the initial samples).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pfem2x.physics.flow._kernels import (
    circle_distance_kernel,
    circle_fit_equations,
    closest_pairs_within_kernel,
    pairs_within_kernel,
)
from pfem2x.physics.flow.interface import InterfaceGeometry, cut_segments, segment_distance

__all__ = [
    "circle_distance",
    "circle_misfit",
    "closest_mean",
    "closest_pairs",
    "closest_pairs_within",
    "distance_curvature",
    "oriented_segments",
    "refined_segments",
    "region_distance",
    "segment_curvature",
    "smooth_along",
    "smooth_quadratic",
]


def oriented_segments(
    vals: np.ndarray, xy: np.ndarray, normals: bool = False
) -> tuple[np.ndarray, ...]:
    """Zero iso-line segments of a P1 field, oriented with phase 1 (values ``>= 0``) on the left.

    Parameters
    ----------
    vals
        ``(n, 3)`` vertex values.
    xy
        ``(n, 3, 2)`` vertex coordinates.

    Returns
    -------
    segs, cells
        ``(m, 2, 2)`` end points (the unit normal ``(-t_y, t_x)`` of the tangent
        ``t = p1 - p0`` points into phase 1) and the ``(m,)`` indices of the cut
        cells (cells that touch the iso-line at a vertex only have no segment);
        with ``normals`` also the ``(m, 2)`` unit gradients of the field on the cells.
    """
    pos = vals >= 0
    cut = np.flatnonzero(pos.any(axis=1) & ~pos.all(axis=1))
    v, x = vals[cut], xy[cut]
    m = len(cut)
    if m == 0:
        return (np.zeros((0, 2, 2)), cut) + ((np.zeros((0, 2)),) if normals else ())
    segs = cut_segments(v, x)  # (every cell of v is cut: one segment each, in order)
    # the gradient of the P1 field on each cell: J^T grad = (v1 - v0, v2 - v0)
    J = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=1)  # rows: edge vectors
    dv = np.stack([v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]], axis=1)
    grad = np.linalg.solve(J, dv[:, :, None])[:, :, 0]
    t = segs[:, 1] - segs[:, 0]
    left = -t[:, 1] * grad[:, 0] + t[:, 0] * grad[:, 1]
    flip = left < 0.0
    segs[flip] = segs[flip][:, ::-1]
    # a cell touching the iso-line at one vertex only: no segment
    size = np.linalg.norm(J, axis=2).max(axis=1)
    keep = np.linalg.norm(t, axis=1) > 1e-12 * size
    if not normals:
        return segs[keep], cut[keep]
    gn = grad / np.maximum(np.linalg.norm(grad, axis=1), 1e-300)[:, None]
    return segs[keep], cut[keep], gn[keep]


def refined_segments(
    vals: np.ndarray, xy: np.ndarray, grads: np.ndarray, segs: np.ndarray, cells: np.ndarray
) -> np.ndarray:
    r"""The end points of :func:`oriented_segments` moved to the root of a quadratic per edge.

    Along a cut edge :math:`x_i + s\,e`, :math:`s \in [0, 1]`, the field is taken as
    :math:`f(s) = v_i + (v_j - v_i)s + \tfrac12 q\,s(s - 1)` with the second derivative
    :math:`q = (g_j - g_i)\cdot e` from the recovered nodal gradients :math:`g` (three
    Newton steps from the linear root). The zero iso-line of a P1 field cuts a curved
    interface's chords, whose offset (:math:`h^2\kappa/8`) varies from edge to edge: the
    noise of the fitted curvature (circle R = 0.25 at h = 1/40, fit and average over 3
    cells: max error 1.3e-2 with the linear end points, 1.6e-4 with these).

    Parameters
    ----------
    vals, xy
        ``(n, 3)`` vertex values and ``(n, 3, 2)`` coordinates, as :func:`oriented_segments`.
    grads
        ``(n, 3, 2)`` recovered gradients at the vertices.
    segs, cells
        The segments and cells :func:`oriented_segments` returned for ``vals``.

    Returns
    -------
    ``(m, 2, 2)`` segments, each end point on the same edge as in ``segs``, same orientation.
    """
    m = len(cells)
    if m == 0:
        return segs.copy()
    v, x, g = vals[cells], xy[cells], grads[cells]
    pos = v >= 0
    crosses = np.empty((m, 3), dtype=bool)
    pts = np.empty((m, 3, 2))
    lin = np.empty((m, 3, 2))
    for e, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        crosses[:, e] = pos[:, i] != pos[:, j]
        ed = x[:, j] - x[:, i]
        q = np.einsum("mk,mk->m", g[:, j] - g[:, i], ed)
        dv = v[:, j] - v[:, i]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crosses[:, e], v[:, i] / (v[:, i] - v[:, j]), 0.0)
            s0 = s
            for _ in range(3):
                f = v[:, i] + dv * s + 0.5 * q * s * (s - 1.0)
                fp = dv + 0.5 * q * (2.0 * s - 1.0)
                s = np.clip(s - f / fp, 0.0, 1.0)
            # a flat or non-monotone quadratic: keep the linear root
            s = np.where(crosses[:, e] & np.isfinite(s), s, s0)
        pts[:, e] = x[:, i] + s[:, None] * ed
        lin[:, e] = x[:, i] + s0[:, None] * ed
    # each end point of segs is the linear root of one crossing edge: the nearest one
    out = np.empty_like(segs)
    for k in range(2):
        d = np.einsum("mek,mek->me", lin - segs[:, k, None, :], lin - segs[:, k, None, :])
        d[~crosses] = np.inf
        out[:, k] = np.take_along_axis(pts, np.argmin(d, axis=1)[:, None, None], axis=1)[:, 0]
    return out


def segment_curvature(
    segs: np.ndarray, radius: float, normals: np.ndarray | None = None
) -> np.ndarray:
    """Curvature of each oriented segment from a least-squares circle of its neighbours.

    Parameters
    ----------
    segs
        ``(m, 2, 2)`` segments oriented as :func:`oriented_segments` returns them.
    radius
        The end points within this distance of a segment's midpoint enter its fit
        (weight :math:`(1 - d^2/r^2)^2` times half the length of the point's segment).
    normals
        ``(m, 2)`` unit normals into phase 1 of the fit frames (default: the
        segments' own; the field's cell gradients are more robust: a segment
        that cuts a cell near a vertex is short and its direction arbitrary).

    Returns
    -------
    ``(m,)`` curvatures, positive where phase 1 (left of the segments) is convex;
    0 where fewer than three points lie within ``radius``.
    """
    m = len(segs)
    if m == 0:
        return np.zeros(0)
    mid = segs.mean(axis=1)
    if normals is None:
        t = segs[:, 1] - segs[:, 0]
        t /= np.maximum(np.linalg.norm(t, axis=1), 1e-300)[:, None]
        n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    else:
        n = normals
        t = np.stack([n[:, 1], -n[:, 0]], axis=1)
    pts = segs.reshape(-1, 2)
    # each end point weighs half its segment's length (a quadrature of the curve: the
    # short segments of a curve passing near a vertex add no spurious weight there)
    plen = np.repeat(0.5 * np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1), 2)
    kappa = np.zeros(m)
    chunk = max(1, 4_000_000 // max(len(pts), 1))
    for k in range(0, m, chunk):  # chunks of segments (memory), all points at once
        sl = slice(k, k + chunk)
        d = pts[None, :, :] - mid[sl, None, :]  # (c, p, 2)
        r2 = np.einsum("cpj,cpj->cp", d, d) / radius**2
        w = np.where(r2 < 1.0, (1.0 - r2) ** 2, 0.0) * plen[None, :]
        s = np.einsum("cpj,cj->cp", d, t[sl])
        eta = np.einsum("cpj,cj->cp", d, n[sl])
        basis = np.stack([s * s + eta * eta, s, np.ones_like(s)], axis=2)  # (c, p, 3)
        M = np.einsum("cp,cpi,cpj->cij", w, basis, basis)
        rhs = np.einsum("cp,cpi,cp->ci", w, basis, eta)
        enough = np.count_nonzero(w > 0.0, axis=1) >= 3
        scale = np.einsum("cii->c", M)[:, None, None] * 1e-13 + 1e-300
        M = M + scale * np.eye(3)[None]
        coef = np.linalg.solve(M, rhs[:, :, None])[:, :, 0]
        A, B, D = coef[:, 0], coef[:, 1], coef[:, 2]
        den = np.sqrt(np.maximum(1.0 + B * B - 4.0 * A * D, 1e-300))
        kappa[sl] = np.where(enough, 2.0 * A / den, 0.0)
    return kappa


def _pairs_within(centres: np.ndarray, points: np.ndarray, radius: float) -> tuple[np.ndarray, ...]:
    """Index pairs ``(centre, point)`` closer than ``radius`` (buckets of side ``radius``).

    Compiled (:func:`~pfem2x.physics.flow._kernels.pairs_within_kernel`).
    """
    return pairs_within_kernel(
        np.ascontiguousarray(centres, dtype=np.float64),
        np.ascontiguousarray(points, dtype=np.float64),
        float(radius),
    )


def distance_curvature(
    segs: np.ndarray,
    normals: np.ndarray,
    points: np.ndarray,
    values: np.ndarray,
    radius: float,
    iterations: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Curvature of each segment from a least-squares fit of the signed-distance data around it.

    The samples ``values`` (signed distances, > 0 in phase 1) at ``points`` within ``radius``
    of a segment's midpoint (weight :math:`(1 - d^2/r^2)^2`) are fitted by
    :math:`\lambda\,d(x)`, :math:`d` the exact signed distance to the circle :math:`\eta =
    A(s^2 + \eta^2) + Bs + D` in the frame of the segment's normal
    (:func:`~pfem2x.physics.flow._kernels._circle_distance`;
    :math:`\lambda` takes up a stretched distance), by Gauss–Newton from the straight line;
    :math:`\kappa = 2A/\sqrt{1 + B^2 - 4AD}`. A circle's exact distances give its curvature
    to round-off, whatever the samples' positions (the end points of the P1 iso-line lie
    on chords, and even on a quadratic per edge they scatter the curvature by 2e-4 at
    h = 1/40).

    Parameters
    ----------
    segs, normals
        ``(m, 2, 2)`` segments and ``(m, 2)`` unit normals into phase 1 (the fit frames).
    points, values
        ``(p, 2)`` sample positions and ``(p,)`` signed distances (nodes, particles).
    radius
        The fit radius.
    iterations
        Gauss–Newton steps.

    Returns
    -------
    kappa, ok, coef
        ``(m,)`` curvatures and whether the fit had at least six samples and converged
        to finite values (where not, ``kappa`` is 0); ``(m, 4)`` the fits'
        :math:`(\lambda, A, B, D)` (in the frame of each segment's midpoint and normal).
    """
    m = len(segs)
    kappa, ok = np.zeros(m), np.zeros(m, dtype=bool)
    if m == 0 or len(points) == 0:
        return kappa, ok, np.zeros((m, 4))
    mid = segs.mean(axis=1)
    ci, pi = _pairs_within(mid, points, radius)
    d = points[pi] - mid[ci]
    w = (1.0 - np.einsum("kj,kj->k", d, d) / radius**2) ** 2
    n = normals[ci]
    s = d[:, 0] * n[:, 1] - d[:, 1] * n[:, 0]
    eta = np.einsum("kj,kj->k", d, n)
    y = values[pi]
    p = np.zeros((m, 4))
    p[:, 0] = 1.0  # (lambda, A, B, D), from the straight line
    for _ in range(iterations):
        # a fit that runs away overflows and ends non-finite: masked here, not ok below
        with np.errstate(all="ignore"):
            M, rhs = circle_fit_equations(ci, s, eta, w, y, p, m)
            M += (np.einsum("cii->c", M)[:, None, None] * 1e-13 + 1e-300) * np.eye(4)[None]
        bad = ~np.isfinite(M).all(axis=(1, 2)) | ~np.isfinite(rhs).all(axis=1)
        M[bad], rhs[bad] = np.eye(4), np.nan
        p += np.linalg.solve(M, rhs[:, :, None])[:, :, 0]
    A, B, D = p[:, 1], p[:, 2], p[:, 3]
    with np.errstate(invalid="ignore"):
        kap = 2.0 * A / np.sqrt(np.maximum(1.0 + B * B - 4.0 * A * D, 1e-300))
    ok = (np.bincount(ci, minlength=m) >= 6) & np.isfinite(kap) & (p[:, 0] > 0.0)
    return np.where(ok, kap, 0.0), ok, p


def circle_misfit(
    segs: np.ndarray, normals: np.ndarray, coef: np.ndarray, points: np.ndarray, radius: float
) -> np.ndarray:
    """Largest distance of the ``points`` near each segment's midpoint (``radius``) to its circle.

    ``segs``, ``normals``, ``coef`` as :func:`distance_curvature` fitted them; ``points``
    ``(p, 2)``, e.g. the end points of the interface's segments (0 where none is near).
    """
    m = len(segs)
    out = np.zeros(m)
    if m == 0 or len(points) == 0:
        return out
    mid = segs.mean(axis=1)
    ci, pi = _pairs_within(mid, points, radius)
    with np.errstate(all="ignore"):
        d = circle_distance(points[pi], segs[ci], normals[ci], coef[ci])
    if len(ci):
        order = np.argsort(ci, kind="stable")
        start = np.flatnonzero(np.r_[True, np.diff(ci[order]) != 0])
        dev = np.where(np.isfinite(d), np.abs(d), np.inf)[order]
        out[ci[order][start]] = np.maximum.reduceat(dev, start)
    return out


def circle_distance(
    points: np.ndarray, segs: np.ndarray, normals: np.ndarray, coef: np.ndarray
) -> np.ndarray:
    """Signed distance of each point ``(n, 2)`` to the circle of its segment (one each).

    ``segs`` ``(n, 2, 2)``, ``normals`` ``(n, 2)`` and ``coef`` ``(n, 4)`` as
    :func:`distance_curvature` fitted them (> 0 on the side of the normal).
    """
    d = points - segs.mean(axis=1)
    s = d[:, 0] * normals[:, 1] - d[:, 1] * normals[:, 0]
    eta = np.einsum("kj,kj->k", d, normals)
    return circle_distance_kernel(
        s, eta, *(np.ascontiguousarray(coef[:, k], dtype=np.float64) for k in (-3, -2, -1))
    )


def smooth_along(segs: np.ndarray, values: np.ndarray, radius: float) -> np.ndarray:
    """Kernel average of per-segment ``values`` over the segments within ``radius``.

    Weights: :math:`(1 - d^2/r^2)^2` of the midpoint distance times the segment
    length (a quadrature along the curve).
    """
    m = len(segs)
    if m == 0:
        return values.copy()
    mid = segs.mean(axis=1)
    length = np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)
    out = np.empty(m)
    chunk = max(1, 4_000_000 // m)
    for k in range(0, m, chunk):
        d = mid[k : k + chunk, None, :] - mid[None, :, :]
        r2 = np.einsum("cpj,cpj->cp", d, d) / radius**2
        w = np.where(r2 < 1.0, (1.0 - r2) ** 2, 0.0) * length[None, :]
        out[k : k + chunk] = (w @ values) / np.maximum(w.sum(axis=1), 1e-300)
    return out


def smooth_quadratic(segs: np.ndarray, values: np.ndarray, radius: float) -> np.ndarray:
    r"""Local quadratic regression of per-segment ``values`` along the interface.

    Around each segment the values of the segments whose midpoints lie within ``radius``
    (weights :math:`(1 - d^2/r^2)^2` times the segment length, as :func:`smooth_along`)
    are fitted by :math:`c_0 + c_1 s + c_2 s^2`, :math:`s` the offset along the segment's
    tangent; the result is :math:`c_0`. A value that varies quadratically along a straight
    interface is kept exactly, where the kernel mean of :func:`smooth_along` is biased by
    :math:`\kappa'' r^2/14` (an ellipse's tips: docs/RESULTS.md, "The curvature's window").
    With fewer than five segments in the window: the kernel mean.
    """
    m = len(segs)
    if m == 0:
        return values.copy()
    mid = segs.mean(axis=1)
    tangent = segs[:, 1] - segs[:, 0]
    length = np.linalg.norm(tangent, axis=1)
    tangent = tangent / np.maximum(length, 1e-300)[:, None]
    ci, pj = _pairs_within(mid, mid, radius)
    d = mid[pj] - mid[ci]
    w = (1.0 - np.einsum("kj,kj->k", d, d) / radius**2) ** 2 * length[pj]
    s = np.einsum("kj,kj->k", d, tangent[ci]) / radius  # (scaled: moments of order 1)
    mom = [np.bincount(ci, w * s**k, minlength=m) for k in range(5)]
    rhs = np.stack([np.bincount(ci, w * s**k * values[pj], minlength=m) for k in range(3)], 1)
    M = np.stack([np.stack(mom[i : i + 3], 1) for i in range(3)], 1)
    M += (1e-14 * np.einsum("kii->k", M) + 1e-300)[:, None, None] * np.eye(3)
    out = np.linalg.solve(M, rhs[:, :, None])[:, 0, 0]
    few = np.bincount(ci, minlength=m) < 5
    out[few] = rhs[few, 0] / np.maximum(mom[0][few], 1e-300)
    return out


def _bisect(
    region: Callable[..., Any], a: np.ndarray, b: np.ndarray, steps: int = 48
) -> np.ndarray:
    """The boundary point of ``region`` between ``a`` and ``b`` ``(n, 2)`` (on opposite sides)."""
    x3 = np.zeros((len(a), 3))
    x3[:, :2] = a
    ina = np.asarray(region(x3, 0.0), dtype=bool)
    for _ in range(steps):
        mid = 0.5 * (a + b)
        x3[:, :2] = mid
        same = np.asarray(region(x3, 0.0), dtype=bool) == ina
        a = np.where(same[:, None], mid, a)
        b = np.where(same[:, None], b, mid)
    return 0.5 * (a + b)


def region_distance(
    interface: InterfaceGeometry,
    region: Callable[..., Any],
    points: np.ndarray | None = None,
    subdivisions: int = 64,
) -> np.ndarray:
    """Signed distance (> 0 inside ``region``) of ``points`` ``(n, 2)`` to its edge (collective).

    ``points`` default: the interface's nodes (owned and ghost).

    The boundary is sampled on the cut edges of the mesh (bisection), each cut cell's chord
    is divided in ``subdivisions`` and its inner points moved along the chord's normal onto
    the boundary (bisection): the distance is that to a polygon whose chords lie within
    :math:`L^2\\kappa/(8\\,\\mathrm{subdivisions}^2)` of the curve (:math:`L` the chord's
    length; measured 1.3e-7 within 3 h of a circle R = 0.25 at h = 1/40), not to the mesh's
    chords (5.4e-4): the initial signed distance the curvature fit
    (:func:`distance_curvature`) takes its samples from. Capped at the interface's clip
    distance, at least 1e-12 of it.
    """
    itf = interface
    x3 = np.zeros((len(itf.coords), 3))
    x3[:, :2] = itf.coords[:, :2]
    ins = np.asarray(region(x3, 0.0), dtype=bool)[itf.dofmap[: itf.n_owned]]
    cut = ins.any(axis=1) & ~ins.all(axis=1)
    xy, ci = itf.cell_xy[cut], ins[cut]
    ends = np.zeros((len(xy), 3, 2))
    crosses = np.zeros((len(xy), 3), dtype=bool)
    for e, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):  # the boundary on the cut edges
        crosses[:, e] = ci[:, i] != ci[:, j]
        ends[:, e] = _bisect(region, xy[:, i], xy[:, j])
    idx = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
    a, b = np.moveaxis(np.take_along_axis(ends, idx[:, :, None], axis=1), 1, 0)
    # the chord's inner points moved along its normal onto the boundary (within half its length)
    nrm = np.stack([a[:, 1] - b[:, 1], b[:, 0] - a[:, 0]], axis=1)[:, None, :]
    frac = (np.arange(1, subdivisions) / subdivisions)[None, :, None]
    base = a[:, None, :] + frac * (b - a)[:, None, :]
    off = 0.5 * nrm  # |nrm|: the chord's length
    inner = base.reshape(-1, 2)
    if len(inner):
        lo, hi = (base - off).reshape(-1, 2), (base + off).reshape(-1, 2)
        x3 = np.zeros((len(lo), 3))
        x3[:, :2] = lo
        s_lo = np.asarray(region(x3, 0.0), dtype=bool)
        x3[:, :2] = hi
        bracket = s_lo != np.asarray(region(x3, 0.0), dtype=bool)
        inner = np.where(bracket[:, None], _bisect(region, lo, hi), inner)
    pts = np.concatenate([a[:, None], inner.reshape(base.shape), b[:, None]], axis=1)
    fine = np.stack([pts[:, :-1], pts[:, 1:]], axis=2).reshape(-1, 2, 2)
    allfine = itf.gather(fine)
    if points is None:
        points = itf.coords[:, :2]
    x3 = np.zeros((len(points), 3))
    x3[:, :2] = points
    sign = np.where(np.asarray(region(x3, 0.0), dtype=bool), 1.0, -1.0)
    # at least 1e-12 of the clip: a point on the boundary takes the region's side, not the
    # sign of a round-off distance (the polygon's points differ by round-off between partitions)
    d = segment_distance(points, allfine, cap=itf.clip)
    return sign * np.clip(d, 1e-12 * itf.clip, itf.clip)


def closest_pairs(
    points: np.ndarray, segs: np.ndarray, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """Pairs ``(point, segment)`` whose distance is within ``tol`` of the point's closest one.

    A point equidistant from two segments (their shared end point is its closest point,
    or a symmetry) is paired with both, not with the one a round-off difference picks
    (which differs between partitions). Sorted by point, then segment.

    The pairs of all points and segments, found without measuring them all: a segment
    within ``tol`` of a point's closest one is at most :math:`d_{max}` + ``tol`` from the
    point (:math:`d_{max}` the largest distance of any point to its closest segment,
    :func:`~pfem2x.physics.flow.interface.segment_distance`), so its midpoint is within
    :math:`d_{max}` + ``tol`` + half the longest segment (:func:`closest_pairs_within`
    with that radius).
    """
    if len(points) == 0 or len(segs) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dmax = float(segment_distance(points, segs).max())
    half = 0.5 * float(np.sqrt(((segs[:, 1] - segs[:, 0]) ** 2).sum(axis=1)).max())
    radius = (dmax + tol + half) * (1.0 + 1e-9) + 1e-300
    return closest_pairs_within(points, segs, radius, tol)


def closest_pairs_within(
    points: np.ndarray, segs: np.ndarray, radius: float, tol: float
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`closest_pairs` among the segments whose midpoint is within ``radius`` of a point.

    The same pairs as :func:`closest_pairs` for every point whose closest segment's
    midpoint is within ``radius`` (buckets of side ``radius``: about ``m`` times the
    points near each segment, not all pairs); a point with no segment that near has none.
    """
    if len(points) == 0 or len(segs) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return closest_pairs_within_kernel(
        np.ascontiguousarray(points, dtype=np.float64),
        np.ascontiguousarray(segs, dtype=np.float64),
        float(radius),
        float(tol),
    )


def closest_mean(
    points: np.ndarray, segs: np.ndarray, values: np.ndarray, tol: float
) -> np.ndarray:
    """Mean of the per-segment ``values`` over each point's :func:`closest_pairs`."""
    pi, si = closest_pairs(points, segs, tol)
    n = len(points)
    return np.bincount(pi, weights=values[si], minlength=n) / np.maximum(
        np.bincount(pi, minlength=n), 1
    )
