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

Curvature of a segment (:mod:`pfem2x.physics.flow.curvature`): a weighted
least-squares fit of the exact signed distance of a circle (times a stretch
:math:`\lambda`) to the signed-distance samples within ``fit_radius`` cells of
its midpoint (:func:`distance_curvature`; the level set: the nodes of the cut
cells, which the re-distancing keeps; PFEM-2: the particles' ``dist``), in the
frame :math:`(s, \eta)` of the cell's gradient (tangent, normal): the circle
:math:`\eta = A(s^2 + \eta^2) + Bs + D`, :math:`\kappa = 2A/\sqrt{1 + B^2 - 4AD}`
(exact for a circle whatever the samples' positions, well conditioned for a
straight line). The samples start as the distance to the region's boundary
sampled below the mesh size (:func:`region_distance`), and the level set's
re-distancing gives the nodes near the interface (not of cut cells) their
distance to the fitted circles (:meth:`CapillaryForce.redistance`): a circle
stays a circle, and the static drop stays at rest to round-off (docs/RESULTS.md);
PFEM-2 re-distances its particles within 3 cells of the interface the same way
(:meth:`CapillaryForce.redistance_samples`, ``flow.particle_redistance``), else the
flow stretches their carried ``dist``.
Where the fit is not trusted (its circle farther than ``h/2`` from the
iso-line's end points around the segment; the samples' distance stretched
by more than 5 %; fewer than six samples) the curvature is the end-point fit:
a weighted least-squares circle of the same form through the end points of
the segments within ``fit_radius`` cells (each moved to the root of a
quadratic along its cut edge, :func:`refined_segments`; :func:`segment_curvature`;
its noise, 2e-4 of :math:`1/R` on a circle at h = 1/40, drove spurious currents
:math:`\mu|u|/\sigma` of 1e-5 to 1e-4). A circle fit over a window of radius
:math:`r` is biased where the curvature varies, by about :math:`\kappa'' r^2`: with
``extrapolate`` (PFEM-2, whose particles are dense enough for the smaller window) the
fits over :math:`r` and :math:`2r/3` are extrapolated to :math:`r \to 0`,
:math:`\kappa = (9\kappa_{2r/3} - 4\kappa_r)/5` (exact for a circle still). Then the
curvatures are smoothed along the interface by a local quadratic fit over
``smooth_radius`` cells (:func:`smooth_quadratic`, exact for a curvature varying
quadratically; without smoothing the saw-tooth capillary waves of the P1 iso-line at
h = 1/80 lowered the rising bubble's circularity by 3 %; with the kernel mean,
:func:`smooth_along`, and the single fit over 3 cells an ellipse of aspect 2.2 lost up to
17 % of its tip curvature at h = 1/40: docs/RESULTS.md, "The curvature's window").

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

``flow.capillary_damping = "normal"``: the same term of the normal velocity
:math:`u\cdot n_h` only,

.. math::
    \Delta t\,\sigma\int_\Gamma \partial_s(u\cdot n_h)\,\partial_s(v\cdot n_h)\,ds
    = \Delta t\,\sigma\sum_{K\ \mathrm{cut}} |s_K|\,
    \big(t_K\cdot\nabla(u\cdot n_h)\big)\big(t_K\cdot\nabla(v\cdot n_h)\big),

:math:`n_h` the P1 unit normal of the recovered nodal gradient of the interface
function. The interface moves with its normal velocity; a flow along it
(the rising bubble's circulation) only re-parametrises it, and the whole-velocity
term damps it as a surface viscosity :math:`\Delta t\,\sigma` (docs/RESULTS.md,
"Rising bubble at large steps").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.physics.flow.curvature import (
    circle_distance,
    circle_misfit,
    closest_mean,
    closest_pairs,
    closest_pairs_within,
    distance_curvature,
    oriented_segments,
    refined_segments,
    region_distance,
    segment_curvature,
    smooth_along,
    smooth_quadratic,
)
from pfem2x.physics.flow.interface import InterfaceGeometry, positive_fraction

__all__ = [
    "CapillaryForce",
    "bubble_geometry",
    "capillary_increment",
    "capillary_dt_limit",
    "distance_curvature",
    "oriented_segments",
    "region_distance",
    "refined_segments",
    "segment_curvature",
    "smooth_along",
]


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
    solver.solve(rhs, sol, guess=False)  # from 0: the predictor's solver starts from û
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
    samples
        The signed-distance samples of the curvature fit (:func:`distance_curvature`):
        ``samples()`` returns this rank's ``(points (p, 2), values (p,))`` (the PFEM-2
        particles' ``dist``); default: the owned nodes of the cut cells and their values.
        Samples farther than ``1.5 h`` from the interface are not used.
    stretch_tolerance
        The distance fit is used where its :math:`|\lambda - 1|` is at most this (samples
        that are still a signed distance; a flow stretches PFEM-2's carried ``dist`` where
        it is not re-distanced: the rising bubble's :math:`\lambda` reached 6 by t = 2 at
        h = 1/40), and where its circle passes within ``h/2`` of the iso-line's end points
        around the segment; elsewhere the end-point fit (:func:`.segment_curvature`).
    damping
        The implicit term (``flow.capillary_damping``): ``"surface"``, of the whole
        velocity; ``"normal"``, of the normal velocity :math:`u\cdot n_h` only (module
        docstring).
    extrapolate
        The segment's curvature extrapolated from the distance fits over ``fit_radius``
        and two thirds of it to a window of radius 0 (Richardson: the fit's bias grows as
        the radius squared); for dense samples (PFEM-2's particles: the level set's nodes
        of the cut cells are too few for the smaller window).
    smooth_radius
        Radius in cells of the quadratic fit along the interface that smooths the
        segments' curvatures (:func:`.smooth_quadratic`).
    """

    def __init__(
        self,
        Q: Any,
        interface: InterfaceGeometry,
        sigma: float,
        band: float,
        h: float,
        fit_radius: float = 3.0,
        samples: Callable[[], tuple[np.ndarray, np.ndarray]] | None = None,
        stretch_tolerance: float = np.inf,
        damping: str = "surface",
        extrapolate: bool = False,
        smooth_radius: float = 4.0,
    ):
        self.interface = interface
        self.samples = samples
        self._sample_band = 1.5 * float(h)
        self._h = float(h)
        #: the distance fit is used where its circle passes within this distance of the
        #: iso-line's end points around the segment (:func:`.curvature.circle_misfit`)
        self.misfit_tolerance = 0.5 * float(h)
        self.misfit = np.zeros(0)  # of the last update, per segment
        #: ... and where the samples' gradient is within this of 1 (the fit's lambda)
        self.stretch_tolerance = float(stretch_tolerance)
        self._n_nodes = Q.dofmap.index_map.size_local
        self.sigma = float(sigma)
        self.band = float(band)
        self.radius = float(fit_radius) * float(h)
        self.smooth_radius = float(smooth_radius) * float(h)
        self.extrapolate = bool(extrapolate)
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
        if damping not in ("surface", "normal"):
            raise ValueError(f"damping must be 'surface' or 'normal', not {damping!r}")
        #: the P1 unit normal n_h of the implicit term's normal velocity (damping = "normal")
        self.normal: Any = None
        if damping == "normal":
            self.normal = compat.dolfinx.fem.Function(
                compat.function_space(mesh, 1, (2,)), name="n_h"
            )
        self._sigma_c = compat.dolfinx.fem.Constant(mesh, compat.PETSc.ScalarType(self.sigma))
        #: smallest and largest segment curvature of the last update
        self.curvature_range = (0.0, 0.0)
        #: segments whose curvature fell back to the end-point fit (no distance fit), of all
        self.fallback_segments = 0
        self.segment_count = 0
        #: the last fit: all segments, their normals, (lambda, A, B, D) and whether its circle
        #: passes the misfit test (whatever its lambda)
        self._circles: tuple[np.ndarray, ...] = (np.zeros((0, 2, 2)),) * 4
        self._kept = np.zeros(len(self._xy), dtype=bool)  # the nodes of the cut cells

    def redistance(self, phi: np.ndarray, band: float) -> None:
        """Nodal values ``phi`` within ``band`` of the interface: the fitted circles' distance.

        After :meth:`update` (its fit, its cut cells): each node within ``band`` that is
        not a node of a cut cell gets the signed distance to the circle fitted to its
        closest segment (:func:`.curvature.circle_distance`; its sign kept; equidistant
        segments: the mean; segments whose fit is not used: unchanged) instead of
        the distance to the P1 iso-line's chords (off by up to :math:`h^2\\kappa/8`):
        a circle stays a circle, and a cell the interface enters next has good samples.
        """
        if not len(self._circles[0]):
            return
        idx = np.flatnonzero(~self._kept & (np.abs(phi) < band))
        dm, has = self._fitted_distance(self._xy[idx], segments=False)
        idx = idx[has]
        phi[idx] = np.where(phi[idx] >= 0.0, 1.0, -1.0) * dm

    def redistance_samples(self, points: np.ndarray, values: np.ndarray, band: float) -> int:
        r"""Samples within ``band`` of the interface: their distance to it (in place; local).

        After :meth:`update` (its fit): each sample ``values`` ``(p,)`` at ``points``
        ``(p, 2)`` with :math:`|v| <` ``band`` gets the distance to the circle fitted to
        its closest segment (:func:`.curvature.circle_distance`; equidistant segments: the
        mean; whatever the fit's stretch :math:`\lambda`), or where that circle misses the
        iso-line (:attr:`misfit_tolerance`) the distance to the segment itself (the
        iso-line's end points on a quadratic per edge), with its own sign. PFEM-2's carried
        ``dist`` is so kept a signed distance (:math:`\lambda = 1`) near the interface,
        where the fit takes its samples; on a circle or a straight line the values do not
        change (to round-off), nor the interface projected from them.

        Returns
        -------
        The number of samples re-distanced.
        """
        if not len(self._circles[0]):
            return 0
        idx = np.flatnonzero(np.abs(values) < band)
        # (the closest segment among those whose midpoint is within band + 2 h: a sample
        # with none that near keeps its value)
        dm, has = self._fitted_distance(points[idx], True, band + 2.0 * self._h)
        idx = idx[has]
        values[idx] = np.where(values[idx] >= 0.0, 1.0, -1.0) * dm
        return len(idx)

    def _fitted_distance(
        self, pts: np.ndarray, segments: bool, near: float = 0.0
    ) -> tuple[np.ndarray, ...]:
        """Distance of ``pts`` to the last fit's circles of their closest segments.

        ``segments``: where a closest segment's fit is not used, the distance to that
        segment, and only segments whose midpoint is within ``near`` of the point count
        (:func:`.curvature.closest_pairs_within`); else such pairs are left out (all
        segments count). Returns the distances of the points that have one and which those
        are (a mask).
        """
        allsegs, normals, coef, ok = self._circles
        if segments:  # (tied segments: the mean of their distances)
            pi, si = closest_pairs_within(pts, allsegs, near, 1e-9 * self.radius)
            good = ok[si]
            d = np.empty(len(pi))
            q, s = pts[pi[good]], si[good]
            d[good] = np.abs(circle_distance(q, allsegs[s], normals[s], coef[s]))
            q, s = pts[pi[~good]], si[~good]
            a, ab = allsegs[s, 0], allsegs[s, 1] - allsegs[s, 0]
            ab2 = np.maximum(np.einsum("kj,kj->k", ab, ab), 1e-300)
            t = np.clip(np.einsum("kj,kj->k", q - a, ab) / ab2, 0.0, 1.0)
            d[~good] = np.linalg.norm(q - a - t[:, None] * ab, axis=1)
        else:
            pi, si = closest_pairs(pts, allsegs, 1e-9 * self.radius)
            good = ok[si]  # (tied segments: the mean of their circles' distances)
            pi, si = pi[good], si[good]
            d = np.abs(circle_distance(pts[pi], allsegs[si], normals[si], coef[si]))
        cnt = np.bincount(pi, minlength=len(pts))
        has = cnt > 0
        return np.bincount(pi, weights=d, minlength=len(pts))[has] / cnt[has], has

    def force(self, H_w: Any) -> Any:
        """The UFL force :math:`f_h` with the frame's phase weight ``H_w``."""
        return ufl.grad(self.Pi) - self._sigma_c * H_w * ufl.grad(self.kappa)

    def implicit_form(self, u: Any, v: Any, dt: Any) -> Any:
        r"""The UFL integrand of the implicit term (times ``dx``: :math:`\Delta t\,\sigma
        \int_\Gamma\nabla_\Gamma u:\nabla_\Gamma v`, or of :math:`u\cdot n_h`,
        :math:`v\cdot n_h` with ``damping = "normal"``)."""
        w = self.w
        if self.normal is not None:  # the normal velocity's tangential derivative only
            n = self.normal
            du, dv = ufl.grad(ufl.dot(u, n)), ufl.grad(ufl.dot(v, n))
            return dt * self._sigma_c * ufl.dot(du, w) * ufl.dot(dv, w)
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

    def _marked_nodes(self, cells: np.ndarray) -> np.ndarray:
        """The nodes (owned and ghost) of the local ``cells`` (a mask) on any rank (collective)."""
        mark = self._mark.x.array
        mark[:] = 0.0
        mark[self.interface.dofmap[cells]] = 1.0
        compat.scatter_reverse_add(self._mark.x)
        compat.scatter_forward(self._mark.x)
        return mark > 0.0

    def _gathered_samples(self, phi: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, ...]:
        """All ranks' signed-distance samples near the interface (collective).

        ``nodes``: the nodes of the cut cells, the default samples.
        """
        if self.samples is not None:
            pts, vals = self.samples()
        else:
            own = np.flatnonzero(nodes[: self._n_nodes])
            pts, vals = self._xy[own], phi[own]
        near = np.abs(vals) < self._sample_band
        local = np.concatenate([pts[near], vals[near, None]], axis=1)
        parts = self.interface.comm.allgather(local)
        both = np.concatenate([p for p in parts if len(p)] or [np.zeros((0, 3))])
        return both[:, :2], both[:, 2]

    def _segment_curvature(
        self, phi: np.ndarray, cell_vol: np.ndarray, marked: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """All ranks' refined segments, cell normals and curvatures (collective).

        The curvature of the distance fit (:func:`distance_curvature`), the end-point fit
        (:func:`segment_curvature`) where it fails, averaged along the interface.
        """
        itf = self.interface
        vals = phi[itf.dofmap[: itf.n_owned]]
        segs, cells, nrm = oriented_segments(vals, itf.cell_xy, normals=True)
        fit = refined_segments(vals, itf.cell_xy, self._nodal_gradient(vals, cell_vol), segs, cells)
        parts = itf.comm.allgather(np.concatenate([fit, nrm[:, None, :]], axis=1))
        both = np.concatenate([p for p in parts if len(p)] or [np.zeros((0, 3, 2))])
        allsegs, normals = both[:, :2], both[:, 2]
        pts, dvals = self._gathered_samples(phi, marked)
        kap, ok, coef = distance_curvature(allsegs, normals, pts, dvals, self.radius)
        # the fitted circle must pass through the iso-line's end points around the segment
        self.misfit = circle_misfit(allsegs, normals, coef, allsegs.reshape(-1, 2), self.radius)
        ok &= self.misfit <= self.misfit_tolerance
        # (the circles of the re-distancing: a stretched distance still fits the shape)
        self._circles = (allsegs, normals, coef, ok.copy())
        # and the samples must be a signed distance (PFEM-2's carried dist: see the tolerance)
        ok &= np.abs(coef[:, 0] - 1.0) <= self.stretch_tolerance
        self.fallback_segments = int(np.count_nonzero(~ok))
        self.segment_count = len(ok)
        if self.extrapolate:
            # the fit's bias grows as the window's radius squared (kappa'' r^2): the fits
            # over 2/3 and all of it, extrapolated to r -> 0
            kap_in, ok_in, _ = distance_curvature(
                allsegs, normals, pts, dvals, self.radius * 2.0 / 3.0
            )
            both = ok & ok_in
            kap[both] = (9.0 * kap_in[both] - 4.0 * kap[both]) / 5.0
        if not ok.all():
            kap[~ok] = segment_curvature(allsegs[~ok], self.radius, normals[~ok])
        return segs, cells, allsegs, smooth_quadratic(allsegs, kap, self.smooth_radius)

    def update(self, phi: np.ndarray, cell_vol: np.ndarray) -> None:
        """Recompute :math:`\\kappa_h`, the potential and the tensor from nodal values ``phi``.

        ``phi`` holds owned and ghost values; ``cell_vol`` the owned cells' areas.
        Collective: the segments and samples are gathered and band marks summed over ranks.
        """
        itf = self.interface
        # the default samples: the nodes of the cells the re-distancing keeps (a sign change)
        allv = phi[itf.dofmap]
        kept = self._marked_nodes((allv.min(axis=1) < 0.0) & (allv.max(axis=1) > 0.0))
        self._kept = kept
        segs, cells, allsegs, kap_all = self._segment_curvature(phi, cell_vol, kept)
        if self.normal is not None:  # (the nodal gradient the curvature fit just recovered)
            g = self._grad.x.array.reshape(-1, 3)[:, :2]
            gn = np.linalg.norm(g, axis=1)
            self.normal.x.array[:] = (g / np.maximum(gn, 1e-300)[:, None]).ravel()
        # the band: nodes of cells with a sign change (phi >= 0 or not) and nodes within `band`
        hpos = phi >= 0.0
        hc = hpos[itf.dofmap]
        mark = self._marked_nodes(hc.any(axis=1) & ~hc.all(axis=1))
        near = mark | (np.abs(phi) < self.band)
        kap = np.zeros(len(phi))
        if len(allsegs) and near.any():
            kap[near] = closest_mean(self._xy[near], allsegs, kap_all, 1e-9 * self.radius)
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
