r"""Surface tension (``effects.surface_tension``): balanced capillary force, semi-implicit.

The capillary force :math:`\sigma\kappa\delta_\Gamma n` (:math:`n` the normal
into phase 1, the phase with a region, :math:`\kappa > 0` where phase 1 is
convex) is written as in :mod:`pfem2x.physics.flow.balanced`,

.. math::
    \sigma\kappa\,\nabla H = \nabla(\sigma\kappa H) - \sigma H\,\nabla\kappa,

and discretised as

.. math::
    f_h = \nabla I_h(\sigma\kappa_h H_h) - \sigma H_w\nabla\kappa_h,

- :math:`H_h`: the nodal sharp Heaviside of the frame's P1 interface function
  (1 where it is :math:`\geq 0`);
- :math:`H_w`: the frame's own phase weight (smoothed level set, particle
  fractions);
- :math:`\kappa_h`: P1, nodal curvature on the band of nodes near the
  interface (the nodes of every cell the phase weight varies on): the
  curvature of the interface segment closest to the node (closest-point
  extension, constant along normals), zero elsewhere.

Where :math:`H_h` and :math:`H_w` are one constant (away from the interface)
:math:`f_h = 0`. With :math:`\kappa_h` constant, :math:`f_h = \nabla I_h(\sigma
\kappa H_h)` is a discrete gradient: a pressure jump :math:`\sigma\kappa`
balances it to round-off (a circle with a uniform curvature stays at rest).

Curvature of a segment: a weighted least-squares circle through the end
points of the segments within ``fit_radius`` cells of its midpoint (each end
point moved to the root of a quadratic along its cut edge,
:func:`refined_segments`: the P1 iso-line's chords scatter the fit 60 x more), in the
frame :math:`(s, \eta)` of the cell's gradient (tangent, normal): :math:`\eta =
A(s^2 + \eta^2) + Bs + D`, :math:`\kappa = 2A/\sqrt{1 + B^2 - 4AD}` (exact
for a circle, well conditioned for a straight line); then averaged along the
interface over the same radius (:func:`smooth_along`: the saw-tooth
capillary waves of the P1 iso-line at h = 1/80 lowered the rising bubble's
circularity by 3 % without).

Semi-implicit (Bänsch 2001, Hysing 2006): the capillary force at the new
time level is :math:`\sigma\int_\Gamma\nabla_\Gamma x^{n+1}:\nabla_\Gamma v`
with :math:`x^{n+1} = x^n + \Delta t\,u^{n+1}`; the explicit part is
:math:`f_h`, the implicit part the Laplace–Beltrami term

.. math::
    \Delta t\,\sigma\int_\Gamma \nabla_\Gamma u : \nabla_\Gamma v\,ds
    = \Delta t\,\sigma\sum_{K\ \mathrm{cut}} |s_K|\,(t_K\cdot\nabla u)\cdot(t_K\cdot\nabla v)

in the momentum (predictor) operator (P1: the gradients are constant per
cell; :math:`s_K`, :math:`t_K` the cell's segment and unit tangent). It is a
UFL form with the DG0 tensor :math:`T_K = |s_K|/|K|\;t_K\otimes t_K`. It
vanishes for a fluid at rest and damps the capillary waves that bind the
explicit step :math:`\Delta t < \sqrt{\bar\rho h^3/(2\pi\sigma)}`
(Brackbill et al. 1992, :math:`\bar\rho` the mean density).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.physics.flow.interface import InterfaceGeometry, positive_fraction

__all__ = [
    "CapillaryForce",
    "bubble_geometry",
    "capillary_increment",
    "capillary_dt_limit",
    "oriented_segments",
    "refined_segments",
    "segment_curvature",
    "smooth_along",
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
    crosses = np.empty((m, 3), dtype=bool)
    pts = np.empty((m, 3, 2))
    p = pos[cut]
    for e, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        crosses[:, e] = p[:, i] != p[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crosses[:, e], v[:, i] / (v[:, i] - v[:, j]), 0.0)
        pts[:, e] = x[:, i] + s[:, None] * (x[:, j] - x[:, i])
    idx = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
    segs = np.take_along_axis(pts, idx[:, :, None], axis=1)
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


def closest_segment(points: np.ndarray, segs: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
    """Index of the segment ``(m, 2, 2)`` closest to each point ``(n, 2)``."""
    n, m = len(points), len(segs)
    a = segs[:, 0]
    ab = segs[:, 1] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
    out = np.zeros(n, dtype=np.int64)
    step = max(1, chunk // max(m, 1))
    for k in range(0, n, step):
        ap = points[k : k + step, None, :] - a[None, :, :]
        s = np.clip(np.einsum("nmj,mj->nm", ap, ab) / ab2, 0.0, 1.0)
        d = ap - s[:, :, None] * ab[None, :, :]
        out[k : k + step] = np.argmin(np.einsum("nmj,nmj->nm", d, d), axis=1)
    return out


def capillary_dt_limit(rho1: float, rho2: float, h: float, sigma: float) -> float:
    r"""The explicit capillary step limit :math:`\sqrt{\bar\rho h^3/(2\pi\sigma)}` (inf: σ = 0).

    :math:`\bar\rho` the mean of the two densities, ``h`` the mesh size.
    """
    if sigma <= 0.0:
        return float("inf")
    return float(np.sqrt(0.5 * (rho1 + rho2) * h**3 / (2.0 * np.pi * sigma)))


def capillary_increment(
    u: Any,
    u_star: Any,
    solver: Any,
    mass: Callable[[Any, Any], None],
    project: Callable[[], None],
) -> None:
    r"""``flow.capillary_increment``: the momentum operator on the force's increment too.

    The predictor's Laplace–Beltrami term damps :math:`u^*`, but the balanced
    forces enter the pressure step, after it: their increment :math:`\Delta =
    u^{n+1} - u^*` is explicit, which bounds the step (a capillary wave of
    frequency :math:`\omega` is stable for :math:`\omega\Delta t \lesssim 1.6`
    only). Here :math:`\Delta` passes the predictor's operator,
    :math:`\delta = A_m^{-1} M_\rho\Delta/\Delta t`, and the pressure step is
    repeated from :math:`u^* + \delta - \Delta` (the forces once more):
    :math:`u^{n+1}` is :math:`u^* + \delta` projected, as if the forces had been
    in the predictor (unconditionally stable for the capillary waves). At rest
    with balanced forces :math:`\Delta = 0`: nothing changes. Costs one more
    momentum and one more pressure solve per step.

    Parameters
    ----------
    u, u_star
        The projected velocity :math:`u^{n+1}` and the predicted :math:`u^*` (P1
        functions); ``u_star`` is overwritten.
    solver
        The predictor's solver (its operator :math:`A_m` assembled for this step).
    mass
        ``mass(x, y)``: :math:`y = M_\rho x/\Delta t` (PETSc vectors).
    project
        Repeats the pressure step from ``u_star`` into ``u``.
    """
    d = compat.petsc_vec(u).copy()
    d.axpy(-1.0, compat.petsc_vec(u_star))
    rhs, sol = d.duplicate(), d.duplicate()
    mass(d, rhs)
    solver.solve(rhs, sol)
    us = compat.petsc_vec(u_star)
    us.axpy(1.0, sol)
    us.axpy(-1.0, d)
    u_star.x.scatter_forward()
    for vec in (d, rhs, sol):
        vec.destroy()
    project()


def bubble_geometry(
    comm: MPI.Comm,
    interface: InterfaceGeometry,
    phi: np.ndarray,
    uy: np.ndarray,
    cell_vol: np.ndarray,
) -> dict[str, float]:
    """Area, centroid, perimeter, circularity and mean vertical velocity of phase 1 (collective).

    Area and centroid of the polygon bounded by the zero iso-line of ``phi``
    (Green's theorem over the oriented segments: exact for the P1 interface of
    a phase 1 that does not touch the boundary); perimeter = total segment
    length; circularity = :math:`2\\sqrt{\\pi A}` / perimeter; rise velocity =
    :math:`\\int_{\\phi > 0} u_y / \\int_{\\phi > 0} 1` (cell fractions times the
    cell mean of the nodal ``uy``).
    """
    vals = phi[interface.dofmap[: interface.n_owned]]
    segs, _ = oriented_segments(vals, interface.cell_xy)
    x0, y0 = segs[:, 0, 0], segs[:, 0, 1]
    x1, y1 = segs[:, 1, 0], segs[:, 1, 1]
    frac = positive_fraction(vals) * cell_vol
    uyc = uy[interface.dofmap[: interface.n_owned]].mean(axis=1)
    local = np.array(
        [
            0.5 * np.sum(x0 * y1 - x1 * y0),
            np.sum((y1 - y0) * (x0 * x0 + x0 * x1 + x1 * x1)) / 6.0,  # int x dA
            -np.sum((x1 - x0) * (y0 * y0 + y0 * y1 + y1 * y1)) / 6.0,  # int y dA
            np.sum(np.hypot(x1 - x0, y1 - y0)),
            np.sum(frac * uyc),
            np.sum(frac),
        ]
    )
    tot = np.zeros_like(local)
    comm.Allreduce(local, tot, op=MPI.SUM)
    area, mx, my, per, mu, fv = tot
    out = {"bubble_area": float(area), "bubble_perimeter": float(per)}
    if area > 0.0 and per > 0.0:
        out["centroid_x"] = float(mx / area)
        out["centroid_y"] = float(my / area)
        out["circularity"] = float(2.0 * np.sqrt(np.pi * area) / per)
    else:
        out["centroid_x"] = out["centroid_y"] = out["circularity"] = float("nan")
    out["rise_velocity"] = float(mu / fv) if fv > 0.0 else float("nan")
    return out


class CapillaryForce:
    r"""The balanced capillary force and the implicit Laplace–Beltrami term (module docstring).

    Parameters
    ----------
    Q
        The P1 space (:math:`\kappa_h` and :math:`I_h(\sigma\kappa_h H_h)`).
    interface
        The mesh partition's :class:`~pfem2x.physics.flow.interface.InterfaceGeometry`.
    sigma
        Surface tension coefficient :math:`\sigma \geq 0`.
    band
        Nodes within this distance of the interface get their :math:`\kappa_i`
        (at least the nodes of the cut cells).
    h
        Mesh size (shortest edge): the curvature fit radius is ``fit_radius * h``.
    fit_radius
        Radius of the curvature fit in cells.
    """

    def __init__(
        self,
        Q: Any,
        interface: InterfaceGeometry,
        sigma: float,
        band: float,
        h: float,
        fit_radius: float = 3.0,
    ):
        self.interface = interface
        self.sigma = float(sigma)
        self.band = float(band)
        self.radius = float(fit_radius) * float(h)
        mesh = Q.mesh
        self._xy = interface.coords[:, :2]
        #: nodal curvature kappa_h (P1) and the potential I_h(sigma kappa_h H_h) (P1)
        self.kappa = compat.dolfinx.fem.Function(Q, name="kappa")
        self.Pi = compat.dolfinx.fem.Function(Q, name="Pi_sigma")
        self._mark = compat.dolfinx.fem.Function(Q)
        #: the recovered nodal gradient (area-weighted cell gradients; the third
        #: component the area sum): the second-order end points of the curvature fit
        self._grad = compat.dolfinx.fem.Function(compat.function_space(mesh, 1, (3,)))
        #: the DG0 vector w_K = sqrt(|s_K|/|K|) t_K of the Laplace-Beltrami term (T = w w^T)
        W = compat.function_space(mesh, 0, (2,), family="DG")
        self.w = compat.dolfinx.fem.Function(W, name="w_lb")
        self._wdofs = compat.dofmap_array(W)[: interface.n_owned, 0]
        self._sigma_c = compat.dolfinx.fem.Constant(mesh, compat.PETSc.ScalarType(self.sigma))
        #: smallest and largest segment curvature of the last update
        self.curvature_range = (0.0, 0.0)

    def force(self, H_w: Any) -> Any:
        """The UFL force :math:`f_h` with the frame's phase weight ``H_w``."""
        return ufl.grad(self.Pi) - self._sigma_c * H_w * ufl.grad(self.kappa)

    def implicit_form(self, u: Any, v: Any, dt: Any) -> Any:
        r"""The UFL integrand of the implicit term (times ``dx``: :math:`\Delta t\,\sigma
        \int_\Gamma\nabla_\Gamma u:\nabla_\Gamma v`)."""
        w = self.w
        return dt * self._sigma_c * ufl.dot(ufl.dot(ufl.grad(u), w), ufl.dot(ufl.grad(v), w))

    def _nodal_gradient(self, vals: np.ndarray, cell_vol: np.ndarray) -> np.ndarray:
        """``(owned cells, 3, 2)`` recovered gradients at the owned cells' vertices (collective).

        The area-weighted mean of the P1 gradients of the cells around each node.
        """
        itf = self.interface
        no = itf.n_owned
        x = itf.cell_xy
        J = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=1)
        dv = np.stack([vals[:, 1] - vals[:, 0], vals[:, 2] - vals[:, 0]], axis=1)
        g = np.linalg.solve(J, dv[:, :, None])[:, :, 0]
        acc = self._grad.x.array.reshape(-1, 3)
        n = len(acc)
        dofs = itf.dofmap[:no].ravel()
        wg = np.repeat(np.concatenate([g * cell_vol[:, None], cell_vol[:, None]], axis=1), 3, 0)
        for c in range(3):
            acc[:, c] = np.bincount(dofs, weights=wg[:, c], minlength=n)[:n]
        compat.scatter_reverse_add(self._grad.x)
        compat.scatter_forward(self._grad.x)
        G = acc[:, :2] / np.maximum(acc[:, 2:], 1e-300)
        return G[itf.dofmap[:no]]

    def update(self, phi: np.ndarray, cell_vol: np.ndarray) -> None:
        """Recompute :math:`\\kappa_h`, the potential and the tensor from nodal values ``phi``.

        ``phi`` holds owned and ghost values; ``cell_vol`` the owned cells' areas.
        Collective: the segments are gathered and band marks summed over ranks.
        """
        itf = self.interface
        no = itf.n_owned
        vals = phi[itf.dofmap[:no]]
        segs, cells, nrm = oriented_segments(vals, itf.cell_xy, normals=True)
        fit = refined_segments(vals, itf.cell_xy, self._nodal_gradient(vals, cell_vol), segs, cells)
        parts = itf.comm.allgather(np.concatenate([fit, nrm[:, None, :]], axis=1))
        both = np.concatenate([p for p in parts if len(p)] or [np.zeros((0, 3, 2))])
        allsegs = both[:, :2]
        kap_all = smooth_along(
            allsegs, segment_curvature(allsegs, self.radius, both[:, 2]), self.radius
        )
        # the band: nodes of cells with a sign change and nodes within `band`
        hpos = phi >= 0.0
        hc = hpos[itf.dofmap]
        mixed = hc.any(axis=1) & ~hc.all(axis=1)
        mark = self._mark.x.array
        mark[:] = 0.0
        mark[itf.dofmap[mixed]] = 1.0
        compat.scatter_reverse_add(self._mark.x)
        compat.scatter_forward(self._mark.x)
        near = (mark > 0.0) | (np.abs(phi) < self.band)
        kap = np.zeros(len(phi))
        if len(allsegs) and near.any():
            kap[near] = kap_all[closest_segment(self._xy[near], allsegs)]
        self.kappa.x.array[:] = kap
        self.Pi.x.array[:] = self.sigma * kap * hpos
        lo = float(kap_all.min()) if len(kap_all) else 0.0
        hi = float(kap_all.max()) if len(kap_all) else 0.0
        self.curvature_range = (lo, hi)
        # the Laplace-Beltrami vector on the owned cut cells, ghosts by scatter
        w = self.w.x.array.reshape(-1, 2)
        w[:] = 0.0
        if len(cells):
            t = segs[:, 1] - segs[:, 0]
            L = np.linalg.norm(t, axis=1)
            tu = t / np.maximum(L, 1e-300)[:, None]
            w[self._wdofs[cells]] = np.sqrt(L / cell_vol[cells])[:, None] * tu
        self.w.x.scatter_forward()
