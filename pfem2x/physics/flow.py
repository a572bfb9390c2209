r"""Incompressible Navier–Stokes, one or two phases, on the fixed P1/P1 mesh.

.. math::
    \rho(\partial_t u + u\cdot\nabla u) = -\nabla p + \nabla\cdot(2\mu\,\varepsilon(u)) + \rho g,
    \qquad \nabla\cdot u = 0.

Frames
------
``eulerian`` (:class:`EulerianFlow`) — the baseline of the paper's comparisons:

1. level set :math:`\phi` (> 0 in the phase that has a ``region``): Crank–Nicolson
   + SUPG with the velocity :math:`u^n`, then geometric redistancing every
   ``flow.reinit_every`` steps (signed distance to the P1 zero iso-line, which
   is kept; values clipped at :math:`\pm 8\varepsilon`);
2. :math:`\rho, \mu` from :math:`\phi^{n+1}` with a smoothed Heaviside of
   half-width :math:`\varepsilon` = ``flow.interface_width`` · H (H: shortest edge);
3. velocity predictor (incremental pressure-correction, Guermond–Quartapelle):
   :math:`\rho(\tilde u - u^n)/\Delta t + \rho\,u^n\cdot\nabla\tilde u
   - \nabla\cdot(2\mu\varepsilon(\tilde u)) = -\nabla p^n + \rho g`, SUPG on the
   convective term (``method.supg``), semi-implicit (Oseen) linearisation;
4. pressure increment :math:`\nabla\cdot(\rho^{-1}\nabla\delta p) = \nabla\cdot\tilde u/\Delta t`
   (constant null space removed, or :math:`\delta p = 0` on outflow sides);
5. correction :math:`u^{n+1} = \tilde u - \Delta t\,\rho^{-1}\nabla\delta p` with the
   :math:`\rho`-weighted lumped mass, :math:`p^{n+1} = p^n + \delta p`.

Equal-order P1/P1 is stabilised only by the splitting (the pressure Laplacian
of step 4 acts like a PSPG term of size :math:`\Delta t`); no extra pressure
stabilisation is added.

Boundaries of a box domain, per side (``flow.left``, ``right``, ``bottom``,
``top``; ``flow.walls`` for the rest): ``slip`` (normal component zero),
``noslip``, ``inflow`` (``flow.inflow_velocity``) and ``outflow`` (do-nothing,
:math:`\delta p = 0`).

Time: the runner works in solver time ``t``; diagnostics also report
``tau = t * flow.time_factor`` (e.g. Tryggvason's units for Rayleigh–Taylor).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem
from pfem2x.cases import make_case
from pfem2x.compat import MPI, PETSc
from pfem2x.expr import Expression
from pfem2x.mesh import Domain
from pfem2x.physics.base import Diverged, Solver
from pfem2x.scene import FLOW_SIDES, Scene, SceneError

__all__ = [
    "EulerianFlow",
    "FlowProblem",
    "cut_segments",
    "make_flow_solver",
    "positive_fraction",
    "segment_distance",
]

_EDGES = ((0, 1), (1, 2), (2, 0))


# --------------------------------------------------------------------------
# Scene data
# --------------------------------------------------------------------------
class FlowProblem:
    """The scene's flow data.

    Attributes
    ----------
    phases:
        ``[(name, density, viscosity, region or None)]``; with two phases the
        one with a region comes first (it is :math:`\\phi > 0`).
    two_phase:
        Whether a level set / phase field is carried.
    gravity:
        ``(gdim,)`` array (zeros without ``effects.gravity``).
    sides:
        Box side name → ``slip | noslip | inflow | outflow``.
    """

    def __init__(self, scene: Scene, gdim: int):
        eff = scene.effects
        fl = scene["flow"]
        phases = []
        for name, ph in scene["phases"].items():
            region = (
                Expression(ph["region"], scene.params, f"phases.{name}.region")
                if "region" in ph
                else None
            )
            mu = float(ph["viscosity"]) if eff["viscosity"] else 0.0
            phases.append((name, float(ph["density"]), mu, region))
        phases.sort(key=lambda p: p[3] is None)
        self.phases = phases
        self.two_phase = bool(eff["two_phase"])
        g = np.zeros(gdim)
        if eff["gravity"]:
            gv = np.asarray(fl["gravity"], dtype=float)
            g[: min(gdim, len(gv))] = gv[:gdim]
        self.gravity = g
        self.sides = {s: (fl[s] or fl["walls"]) for s in FLOW_SIDES[: 2 * gdim]}
        self.initial_velocity = (
            scene.vector_expr("flow", "initial_velocity", gdim)
            if fl["initial_velocity"] is not None
            else None
        )
        self.inflow_velocity = (
            scene.vector_expr("flow", "inflow_velocity", gdim)
            if fl["inflow_velocity"] is not None
            else None
        )
        if "inflow" in self.sides.values() and self.inflow_velocity is None:
            raise SceneError("flow.inflow_velocity: required with an inflow side")
        self.velocity_scale = scene.expr("flow", "velocity_scale").value()
        self.time_factor = scene.expr("flow", "time_factor").value()
        self.max_speed = scene.expr("flow", "max_speed").value()
        self.interface_width = float(fl["interface_width"])
        self.reinit_every = int(fl["reinit_every"])
        self.rtol = float(fl["rtol"])
        self.correction = str(fl["correction"])
        self.incremental = fl["pressure_step"] == "increment"
        self.quadrature_degree = int(fl["quadrature_degree"])


# --------------------------------------------------------------------------
# P1 level-set geometry (vectorised, triangles)
# --------------------------------------------------------------------------
def positive_fraction(vals: np.ndarray) -> np.ndarray:
    """Area fraction of each triangle where the linear interpolant of ``vals`` is > 0.

    Parameters
    ----------
    vals:
        ``(n, 3)`` vertex values.

    Returns
    -------
    ``(n,)`` fractions in [0, 1].
    """
    v = np.where(vals == 0.0, 1e-300, vals)
    npos = np.count_nonzero(v > 0, axis=1)
    s = np.sort(v, axis=1)
    # the odd vertex: the positive one (npos == 1) or the negative one (npos == 2)
    a = np.where(npos == 1, s[:, 2], s[:, 0])
    b = np.where(npos == 1, s[:, 0], s[:, 1])
    c = np.where(npos == 1, s[:, 1], s[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        f = a * a / ((a - b) * (a - c))
    f = np.clip(np.nan_to_num(f), 0.0, 1.0)
    out = np.where(npos == 1, f, 1.0 - f)
    out = np.where(npos == 3, 1.0, out)
    return np.where(npos == 0, 0.0, out)


def cut_segments(vals: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Zero iso-line segments of a P1 field on triangles.

    Parameters
    ----------
    vals:
        ``(n, 3)`` vertex values.
    xy:
        ``(n, 3, 2)`` vertex coordinates.

    Returns
    -------
    ``(m, 2, 2)`` segment end points, one per cut triangle.
    """
    pos = vals >= 0
    cut = pos.any(axis=1) & ~pos.all(axis=1)
    v, x, p = vals[cut], xy[cut], pos[cut]
    pts = np.empty((len(v), 3, 2))
    crosses = np.empty((len(v), 3), dtype=bool)
    for e, (i, j) in enumerate(_EDGES):
        crosses[:, e] = p[:, i] != p[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crosses[:, e], v[:, i] / (v[:, i] - v[:, j]), 0.0)
        pts[:, e] = x[:, i] + s[:, None] * (x[:, j] - x[:, i])
    idx = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
    return np.take_along_axis(pts, idx[:, :, None], axis=1)


def segment_distance(
    points: np.ndarray, segs: np.ndarray, cap: float | None = None, chunk: int = 4_000_000
) -> np.ndarray:
    """Distance from each point ``(n, 2)`` to the nearest of the segments ``(m, 2, 2)``.

    Parameters
    ----------
    points
        Query points, shape ``(n, 2)``.
    segs
        Segments, shape ``(m, 2, 2)`` (two end points each).
    cap
        Only distances up to ``cap`` are needed: a point farther than ``cap`` from
        every segment gets ``inf`` (or a distance ``> cap``). Segments are then
        binned into square buckets and each point is measured only against the
        segments within ``cap`` of its bucket, which turns the all-pairs cost
        ``n * m`` into about ``m * (points within cap of a segment)``.
    chunk
        Largest number of point-segment pairs measured at once (memory bound).

    Returns
    -------
    numpy.ndarray
        Distances, shape ``(n,)``; exact wherever they are ``<= cap``.
    """
    n, m = len(points), len(segs)
    out = np.full(n, np.inf)
    if m == 0 or n == 0:
        return out
    a = segs[:, 0]
    ab = segs[:, 1] - a
    ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)

    def measure(pi: np.ndarray, si: np.ndarray) -> np.ndarray:
        ap = points[pi] - a[si]
        s = np.clip(np.einsum("kj,kj->k", ap, ab[si]) / ab2[si], 0.0, 1.0)
        d = ap - s[:, None] * ab[si]
        return np.einsum("kj,kj->k", d, d)

    def all_pairs() -> np.ndarray:
        step = max(1, chunk // m)
        for k in range(0, n, step):
            ap = points[k : k + step, None, :] - a[None, :, :]
            s = np.clip(np.einsum("nmj,mj->nm", ap, ab) / ab2, 0.0, 1.0)
            d = ap - s[:, :, None] * ab[None, :, :]
            out[k : k + step] = np.sqrt(np.min(np.einsum("nmj,nmj->nm", d, d), axis=1))
        return out

    if cap is None or not np.isfinite(cap) or cap <= 0.0:
        return all_pairs()
    # buckets of side b; a segment is listed in every bucket its box (grown by cap) touches
    lo = np.minimum(points.min(axis=0), segs.reshape(-1, 2).min(axis=0)) - cap
    hi = np.maximum(points.max(axis=0), segs.reshape(-1, 2).max(axis=0)) + cap
    b = max(0.5 * cap, float(np.sqrt(np.prod(hi - lo) / (4.0 * n + 4.0 * m))))
    nb = np.maximum(1, np.ceil((hi - lo) / b).astype(np.int64))

    def cell(xy: np.ndarray) -> np.ndarray:
        return np.clip(((xy - lo) / b).astype(np.int64), 0, nb - 1)

    i0 = cell(np.minimum(segs[:, 0], segs[:, 1]) - cap)
    i1 = cell(np.maximum(segs[:, 0], segs[:, 1]) + cap)
    span = i1 - i0 + 1
    cnt = span[:, 0] * span[:, 1]
    if cnt.sum() > max(chunk, 64 * (n + m)):  # long segments: bucket lists would not pay
        return all_pairs()
    seg_of = np.repeat(np.arange(m), cnt)
    k = np.arange(len(seg_of)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    bx = i0[seg_of, 0] + k // span[seg_of, 1]
    by = i0[seg_of, 1] + k % span[seg_of, 1]
    bucket = bx * nb[1] + by
    order = np.argsort(bucket, kind="stable")
    seg_sorted = seg_of[order]
    ptr = np.zeros(nb[0] * nb[1] + 1, dtype=np.int64)
    np.cumsum(np.bincount(bucket, minlength=nb[0] * nb[1]), out=ptr[1:])
    pc = cell(points)
    pb = pc[:, 0] * nb[1] + pc[:, 1]
    c = ptr[pb + 1] - ptr[pb]
    has = np.flatnonzero(c)
    cs = np.cumsum(c[has])
    first = 0
    while first < len(has):  # chunks of whole points, about `chunk` pairs each
        last = int(np.searchsorted(cs, (cs[first - 1] if first else 0) + chunk, side="right"))
        last = max(last, first + 1)
        pts = has[first:last]
        cc = c[pts]
        pi = np.repeat(pts, cc)
        off = np.arange(len(pi)) - np.repeat(np.cumsum(cc) - cc, cc)
        si = seg_sorted[np.repeat(ptr[pb[pts]], cc) + off]
        d2 = measure(pi, si)
        out[pts] = np.sqrt(np.minimum.reduceat(d2, np.cumsum(cc) - cc))
        first = last
    return out


# --------------------------------------------------------------------------
# Solvers
# --------------------------------------------------------------------------
class FlowBase(Solver):
    """Spaces, fields, boundary conditions and diagnostics shared by the flow frames."""

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        if domain.gdim != 2:
            raise SceneError("mesh.kind: flow is available on 2D meshes only (for now)")
        if any(domain.periodic):
            raise SceneError("mesh.periodic: periodic flow is not available yet")
        self.problem = pr = FlowProblem(scene, domain.gdim)
        mesh = domain.mesh
        self.gdim = gdim = domain.gdim
        self.Q = compat.function_space(mesh, 1)
        self.V = compat.function_space(mesh, 1, (gdim,))
        self.coords = self.Q.tabulate_dof_coordinates()
        self.u = compat.dolfinx.fem.Function(self.V, name="u")
        self.p = compat.dolfinx.fem.Function(self.Q, name="p")
        if pr.initial_velocity is not None:
            arr = self.u.x.array.reshape(-1, gdim)
            for i, e in enumerate(pr.initial_velocity):
                arr[:, i] = e(self.coords, 0.0)
        self.H = domain.min_h()
        self.eps = pr.interface_width * self.H
        tab = domain.table
        self.n_owned = tab.num_cells_owned
        self.dofmap = compat.dofmap_array(self.Q)[: tab.num_cells]
        self.cell_xy = self.coords[self.dofmap[: self.n_owned]][:, :, :gdim]
        self.cell_vol = tab.volume[: self.n_owned]
        # gradients of the barycentric coordinates (for div u), ordered like the dofmap
        inv = tab.inv_map[: self.n_owned]
        gl = np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)
        self._gradlam = gl  # (n, 3, gdim)
        self._hcell = tab.h_edge[: self.n_owned]
        # -g.x at the cell centroids: potential energy = sum rho_K |K| (-g.x_K) (exact for DG0 rho)
        g = pr.gravity[:gdim]
        self._gravity_height = -(self.cell_xy.mean(axis=1) @ g) if np.any(g) else None
        self.phi: Any = None
        self.phase: Any = None
        if pr.two_phase:
            self.phi = compat.dolfinx.fem.Function(self.Q, name="phi")
            self.phase = compat.dolfinx.fem.Function(self.Q, name="phase")
            self._keep = compat.dolfinx.fem.Function(self.Q)  # re-distancing: frozen nodes
            self._init_levelset()
        self.dt_last = 0.0
        self.steps_done = 0
        self._bcs_u, self._bcs_p, self._inflow = self._boundary_conditions()
        self.volume0: dict[str, float] = {}
        self.volume0 = self._phase_volumes()
        self.case = make_case(scene["scene"]["case"], self)  # scene.case diagnostics

    # -- boundaries -----------------------------------------------------------
    def _boundary_conditions(self) -> tuple[list, list, Any]:
        pr = self.problem
        lo, hi = self.domain.bounds
        tol = 1e-8 * float(np.max(hi - lo))
        mesh = self.domain.mesh
        bcs_u, bcs_p = [], []
        inflow = None
        for k, side in enumerate(FLOW_SIDES[: 2 * self.gdim]):
            axis, val = k // 2, (lo if k % 2 == 0 else hi)[k // 2]
            kind = pr.sides[side]
            facets = compat.locate_boundary_facets(
                mesh, lambda x, a=axis, v=val: np.abs(x[a] - v) < tol
            )
            if kind == "slip":
                bcs_u.append(compat.dirichlet_component(self.V, axis, facets, 0.0))
            elif kind in ("noslip", "inflow"):
                g = compat.dolfinx.fem.Function(self.V)
                if kind == "inflow":
                    inflow = g if inflow is None else inflow
                    g = inflow
                bcs_u.append(compat.dirichlet_component(self.V, None, facets, g))
            elif kind == "outflow":
                dofs = compat.dolfinx.fem.locate_dofs_topological(
                    self.Q, mesh.topology.dim - 1, facets
                )
                bcs_p.append(compat.dolfinx.fem.dirichletbc(PETSc.ScalarType(0.0), dofs, self.Q))
        return bcs_u, bcs_p, inflow

    def _update_inflow(self, t: float) -> None:
        if self._inflow is None:
            return
        arr = self._inflow.x.array.reshape(-1, self.gdim)
        for i, e in enumerate(self.problem.inflow_velocity):
            arr[:, i] = e(self.coords, t)

    # -- level set ------------------------------------------------------------
    def _heaviside_nodes(self, phi: np.ndarray) -> np.ndarray:
        e = self.eps
        s = np.clip(phi / e, -1.0, 1.0)
        return np.where(
            phi <= -e, 0.0, np.where(phi >= e, 1.0, 0.5 * (1 + s + np.sin(np.pi * s) / np.pi))
        )

    def heaviside(self, phi: Any) -> Any:
        """Smoothed Heaviside of a UFL level set (half-width ``eps``)."""
        e = self._eps_c
        return ufl.conditional(
            ufl.lt(phi, -e),
            0.0,
            ufl.conditional(
                ufl.gt(phi, e), 1.0, 0.5 * (1 + phi / e + ufl.sin(np.pi * phi / e) / np.pi)
            ),
        )

    def _segments_global(self, segs: np.ndarray) -> np.ndarray:
        parts = self.comm.allgather(segs)
        return np.concatenate([s for s in parts if len(s)] or [np.zeros((0, 2, 2))])

    def _init_levelset(self) -> None:
        """Signed distance to the region's boundary (edge crossings by bisection)."""
        region = self.problem.phases[0][3]
        inside = np.asarray(region(self.coords, 0.0), dtype=bool)
        ci = inside[self.dofmap[: self.n_owned]]
        cut = ci.any(axis=1) & ~ci.all(axis=1)
        xy, cin = self.cell_xy[cut], ci[cut]
        pts = np.zeros((len(xy), 3, 2))
        crosses = np.zeros((len(xy), 3), dtype=bool)
        for e, (i, j) in enumerate(_EDGES):
            crosses[:, e] = cin[:, i] != cin[:, j]
            a, b = xy[:, i].copy(), xy[:, j].copy()
            ina = cin[:, i]
            for _ in range(40):
                m = 0.5 * (a + b)
                mm = np.zeros((len(m), 3))
                mm[:, :2] = m
                same = np.asarray(region(mm, 0.0), dtype=bool) == ina
                a = np.where(same[:, None], m, a)
                b = np.where(same[:, None], b, m)
            pts[:, e] = 0.5 * (a + b)
        idx = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
        segs = np.take_along_axis(pts, idx[:, :, None], axis=1)
        d = segment_distance(self.coords[:, :2], self._segments_global(segs), cap=self._clip())
        self.phi.x.array[:] = np.where(inside, 1.0, -1.0) * np.minimum(d, self._clip())
        self._update_phase()

    def _clip(self) -> float:
        return 8.0 * self.eps

    def redistance(self) -> None:
        """Geometric redistancing: signed distance to the current zero iso-line (clipped)."""
        phi = self.phi.x.array
        vals = phi[self.dofmap[: self.n_owned]]
        segs = self._segments_global(cut_segments(vals, self.cell_xy))
        L = self._clip()
        near = np.abs(phi) < 2.0 * L
        new = np.sign(phi) * L
        d = segment_distance(self.coords[near, :2], segs, cap=L)
        new[near] = np.where(phi[near] >= 0, 1.0, -1.0) * np.minimum(d, L)
        # the nodes of cut cells keep their values: the zero iso-line does not move
        # (re-distancing them too moved the bubble tip of Rayleigh-Taylor up by
        # 0.06 d at tau = 2 over 500 steps)
        allv = phi[self.dofmap]
        cut = (allv.min(axis=1) < 0.0) & (allv.max(axis=1) > 0.0)
        mark = self._keep.x.array
        mark[:] = 0.0
        mark[self.dofmap[cut]] = 1.0
        compat.scatter_reverse_add(self._keep.x)  # the owner learns of cut cells it lacks
        compat.scatter_forward(self._keep.x)
        keep = mark > 0.0
        new[keep] = phi[keep]
        self.phi.x.array[:] = new

    def _update_phase(self) -> None:
        if self.phase is not None:
            self.phase.x.array[:] = self._heaviside_nodes(self.phi.x.array)

    # -- diagnostics ----------------------------------------------------------
    def _phase_volumes(self) -> dict[str, float]:
        names = [p[0] for p in self.problem.phases]
        total = float(self.comm.allreduce(self.cell_vol.sum(), op=MPI.SUM))
        if not self.problem.two_phase:
            return {names[0]: total}
        vals = self.phi.x.array[self.dofmap[: self.n_owned]]
        v1 = float(self.comm.allreduce(np.dot(positive_fraction(vals), self.cell_vol), op=MPI.SUM))
        return {names[0]: v1, names[1]: total - v1}

    def interfaces(self) -> np.ndarray | None:
        """This rank's segments ``(m, 2, 2)`` of the interface (zero iso-line of ``phi``)."""
        if self.phi is None:
            return None
        vals = self.phi.x.array[self.dofmap[: self.n_owned]]
        return cut_segments(vals, self.cell_xy[: self.n_owned])

    def tips(self) -> tuple[float, float]:
        """Lowest and highest y of the zero iso-line of the level set (global)."""
        vals = self.phi.x.array[self.dofmap[: self.n_owned]]
        ys = []
        for i, j in _EDGES:
            vi, vj = vals[:, i], vals[:, j]
            c = (vi >= 0) != (vj >= 0)
            s = vi[c] / (vi[c] - vj[c])
            ys.append(self.cell_xy[c, i, 1] + s * (self.cell_xy[c, j, 1] - self.cell_xy[c, i, 1]))
        y = np.concatenate(ys)
        lo = float(self.comm.allreduce(y.min() if len(y) else np.inf, op=MPI.MIN))
        hi = float(self.comm.allreduce(y.max() if len(y) else -np.inf, op=MPI.MAX))
        return lo, hi

    def _nodal_density(self) -> np.ndarray:
        ph = self.problem.phases
        if not self.problem.two_phase:
            return np.full(len(self.coords), ph[0][1])
        h = self.phase.x.array
        return ph[1][1] + (ph[0][1] - ph[1][1]) * h

    def _cell_density(self) -> np.ndarray:
        """Density of each owned cell (kinetic energy): mean of the nodal densities."""
        return self._nodal_density()[self.dofmap[: self.n_owned]].mean(axis=1)

    def diagnostics(self, t: float) -> dict[str, float]:
        comm = self.comm
        u = self.u.x.array.reshape(-1, self.gdim)
        uc = u[self.dofmap[: self.n_owned]]  # (n, 3, gdim)
        div = np.einsum("ckj,ckj->c", uc, self._gradlam)
        speed_c = np.linalg.norm(uc, axis=2).max(axis=1) if len(uc) else np.zeros(0)
        rho_c = self._cell_density()
        # exact for P1 u: int_K |u|^2 = |K| / (d+1)(d+2) (sum_i |u_i|^2 + |sum_i u_i|^2)
        nv = uc.shape[1]
        u2 = (np.sum(uc**2, axis=(1, 2)) + np.sum(uc.sum(axis=1) ** 2, axis=1)) / (nv * (nv + 1))
        ke = 0.5 * np.sum(rho_c * u2 * self.cell_vol)
        d = {
            "tau": t * self.problem.time_factor,
            "kinetic_energy": float(comm.allreduce(ke, op=MPI.SUM)),
            "div_max": float(comm.allreduce(np.abs(div).max() if len(div) else 0.0, op=MPI.MAX)),
            "speed_max": float(comm.allreduce(speed_c.max() if len(speed_c) else 0.0, op=MPI.MAX)),
            "courant": float(
                comm.allreduce(
                    (speed_c * self.dt_last / self._hcell).max() if len(speed_c) else 0.0,
                    op=MPI.MAX,
                )
            ),
        }
        if self._gravity_height is not None:
            pe = float(np.sum(rho_c * self.cell_vol * self._gravity_height))
            d["potential_energy"] = float(comm.allreduce(pe, op=MPI.SUM))
        for name, v in self._phase_volumes().items():
            d[f"volume_{name}"] = v
            v0 = self.volume0.get(name, v)
            d[f"volume_change_{name}"] = (v - v0) / v0 if v0 else 0.0
        if self.problem.two_phase:
            d["tip_falling"], d["tip_rising"] = self.tips()
        d.update(self.case.diagnostics(self, t))
        return d

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        if not history:
            return {}
        out: dict[str, Any] = {
            "kinetic_energy_final": history[-1]["kinetic_energy"],
            "div_max": max(h["div_max"] for h in history),
            "courant_max": max(h["courant"] for h in history),
            "speed_max": max(h["speed_max"] for h in history),
        }
        if "potential_energy" in history[0]:
            # kinetic energy against the potential energy released since the start
            released = [history[0]["potential_energy"] - h["potential_energy"] for h in history]
            excess = [h["kinetic_energy"] - r for h, r in zip(history, released, strict=True)]
            out["energy_released_final"] = released[-1]
            top = max(max(released), max(h["kinetic_energy"] for h in history))
            out["energy_excess_max"] = max(excess) / top if top > 0.0 else 0.0
        for name, *_ in self.problem.phases:
            out[f"volume_{name}"] = [history[0][f"volume_{name}"], history[-1][f"volume_{name}"]]
            out[f"volume_change_{name}"] = history[-1][f"volume_change_{name}"]
            out[f"volume_change_max_{name}"] = max(abs(h[f"volume_change_{name}"]) for h in history)
        if self.problem.two_phase:
            out["tip_falling"] = [[h["tau"], h["tip_falling"]] for h in history]
            out["tip_rising"] = [[h["tau"], h["tip_rising"]] for h in history]
        out["tau_factor"] = self.problem.time_factor
        out.update(self.case.metrics(history))
        return out

    # -- pressure projection (shared by the frames) ---------------------------
    def _setup_projection(self, rho: Any, f_body: Any, dxq: Any) -> None:
        """Forms of the pressure increment, the correction and the hydrostatic start.

        Needs ``self.dt_c`` (a Constant). Creates ``u_star`` (the predicted
        velocity) and ``dp`` (the pressure increment):
        ``int rho^-1 grad(dp).grad(r) = -dt^-1 int div(u*) r``, then
        ``u = u* - dt M_rho^-1 int grad(dp).w`` with the rho-weighted lumped
        mass ``M_rho`` (``b_mass``).

        Parameters
        ----------
        rho:
            UFL density (smoothed level set, a DG0 function, a constant).
        f_body:
            UFL body force per volume (:math:`\rho g`), for the hydrostatic start;
            ``None`` without gravity.
        dxq:
            The cell measure.
        """
        V, Q = self.V, self.Q
        self.u_star = compat.dolfinx.fem.Function(V)
        self.dp = compat.dolfinx.fem.Function(Q)
        q, r = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        w = ufl.TestFunction(V)
        self.a_p = compat.form((1.0 / rho) * ufl.dot(ufl.grad(q), ufl.grad(r)) * dxq)
        self.L_p = compat.form(-(1.0 / self.dt_c) * ufl.div(self.u_star) * r * dxq)
        #: the body force (UFL) in the forms; None without effects.gravity (nothing assembled)
        self.body_force = f_body
        self.L_p0 = (
            compat.form((1.0 / rho) * ufl.dot(f_body, ufl.grad(r)) * dxq)
            if f_body is not None
            else None
        )
        self.A_p = None
        self.b_p = compat.create_vector(self.L_p)
        self.p_solver: fem.LinearSolver | None = None
        self.nullspace = None
        ones = ufl.as_vector([1.0] * self.gdim)
        self.L_mass = compat.form(rho * ufl.dot(w, ones) * dxq)
        self.b_mass = compat.create_vector(self.L_mass)
        # the plain lumped mass M (assembled once)
        self.b_lumped = compat.create_vector(self.L_mass)
        fem.assemble_vector(compat.form(ufl.dot(w, ones) * dxq), self.b_lumped)
        if self.problem.correction == "velocity":
            # u -= dt M^-1 int rho^-1 grad(dp).w: the pressure equation's own 1/rho
            self.L_c = compat.form(ufl.dot(ufl.grad(self.dp), w) / rho * dxq)
        else:
            self.L_c = compat.form(ufl.dot(ufl.grad(self.dp), w) * dxq)
        self.b_c = compat.create_vector(self.L_c)
        self.iterations: dict[str, int] = {}

    def _pressure_operator(self) -> None:
        self.A_p = fem.assemble_matrix(self.a_p, self._bcs_p, self.A_p)
        if not self._bcs_p:
            self.nullspace = compat.constant_nullspace(self.A_p)
        if self.p_solver is None:
            self.p_solver = fem.LinearSolver(
                self.A_p, "cg", self.scene["method"]["preconditioner"], rtol=self.problem.rtol
            )
        else:
            self.p_solver.set_operator(self.A_p)

    def _solve_pressure(self, L: Any, x: Any) -> None:
        fem.assemble_vector(L, self.b_p, self.a_p, self._bcs_p)
        if self.nullspace is not None:
            self.nullspace.remove(self.b_p)
        t0 = time.perf_counter()
        self.iterations["pressure"] = self.p_solver.solve(self.b_p, compat.petsc_vec(x))
        x.x.scatter_forward()
        self.timings["solve"] += time.perf_counter() - t0

    def _initial_pressure(self) -> None:
        """Hydrostatic start: div(rho^-1 (grad p - rho g)) = 0."""
        self._pressure_operator()
        self._solve_pressure(self.L_p0, self.p)

    def _correct(self, dt: float, mass_ready: bool = False) -> None:
        """``u = u* - dt M^-1 grad(dp)``, Dirichlet values, ``p += dp`` (or ``p = dp``).

        ``flow.correction``: ``M^-1 int rho^-1 grad(dp).w`` (velocity) or
        ``M_rho^-1 int grad(dp).w`` (momentum). ``flow.pressure_step = "total"``:
        ``dp`` is the whole pressure. ``mass_ready``: ``b_mass`` already holds
        the lumped mass of the current density.
        """
        fem.assemble_vector(self.L_c, self.b_c)
        if self.problem.correction == "velocity":
            mass = self.b_lumped
        else:
            if not mass_ready:
                fem.assemble_vector(self.L_mass, self.b_mass)
            mass = self.b_mass
        n = len(self.b_c.array_r)
        self.u.x.array[:n] = self.u_star.x.array[:n] - dt * self.b_c.array_r / mass.array_r
        compat.set_bc(compat.petsc_vec(self.u), self._bcs_u)
        self.u.x.scatter_forward()
        if self.problem.incremental:
            self.p.x.array[:] += self.dp.x.array
        else:
            self.p.x.array[:] = self.dp.x.array

    # -- API ------------------------------------------------------------------
    def max_velocity(self, t: float) -> float:
        arr = self.u.x.array.reshape(-1, self.gdim)
        local = float(np.max(np.linalg.norm(arr, axis=1))) if len(arr) else 0.0
        vmax = float(self.comm.allreduce(local, op=MPI.MAX))
        return vmax if vmax > 0.0 else self.problem.velocity_scale

    def energy_scale(self) -> float:
        """``1/2 rho_max U^2 |Omega|`` with ``U`` = ``flow.velocity_scale`` (energy guard)."""
        rho = max(ph[1] for ph in self.problem.phases)
        vol = float(self.comm.allreduce(self.cell_vol.sum(), op=MPI.SUM))
        return 0.5 * rho * self.problem.velocity_scale**2 * vol

    def time_label(self, t: float) -> str:
        """Solver time and the scene's other time unit (e.g. Tryggvason's tau)."""
        f = self.problem.time_factor
        return f"t = {t:.4g}" if f == 1.0 else f"t = {t:.4g} (tau = {t * f:.4g})"

    def fields(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.phase is not None:
            out["phase"] = self.phase
            out["phi"] = self.phi
        out["u"] = self.u
        out["p"] = self.p
        return out

    def _check(self) -> None:
        for name, f in self.fields().items():
            bad = 0 if np.all(np.isfinite(f.x.array)) else 1
            if self.comm.allreduce(bad, op=MPI.MAX):
                raise Diverged(f"field {name} is not finite")
        if self.problem.max_speed > 0:
            vmax = self.max_velocity(0.0)
            if vmax > self.problem.max_speed:
                raise Diverged(
                    f"speed {vmax:.3g} exceeds flow.max_speed = {self.problem.max_speed:.3g}"
                )


class EulerianFlow(FlowBase):
    """Fractional-step P1/P1 NS with SUPG and a SUPG level set (see the module docstring)."""

    name = "flow-eulerian"

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        pr = self.problem
        mesh = domain.mesh
        V, Q = self.V, self.Q
        sc = PETSc.ScalarType
        self.dt_c = compat.dolfinx.fem.Constant(mesh, sc(1.0))
        self._eps_c = compat.dolfinx.fem.Constant(mesh, sc(self.eps))
        dt = self.dt_c
        h = ufl.CellDiameter(mesh)
        # the smoothed Heaviside (sin) and SUPG (sqrt) would make UFL pick very high degrees
        dxq = ufl.dx(domain=mesh, metadata={"quadrature_degree": pr.quadrature_degree})
        supg = bool(scene["method"]["supg"])
        self.u_n = compat.dolfinx.fem.Function(V)
        un = self.u_n
        g = compat.dolfinx.fem.Constant(mesh, np.asarray(pr.gravity, dtype=sc))
        (_, r1, m1, _) = pr.phases[0]
        if pr.two_phase:
            (_, r2, m2, _) = pr.phases[1]
            H = self.heaviside(self.phi)
            rho = r2 + (r1 - r2) * H
            mu = m2 + (m1 - m2) * H
        else:
            rho = compat.dolfinx.fem.Constant(mesh, sc(r1))
            mu = compat.dolfinx.fem.Constant(mesh, sc(m1))
        self._rho = rho
        # Gravity as rho g with the full pressure. (The interFoam-style p_rgh form,
        # force -(g.x) grad rho, was tried: twice the spurious wall currents of a
        # flat interface at rest on P1/P1, so it is not used.)
        fg = rho * g if np.any(pr.gravity) else None  # no body force without gravity
        self._f_grav = fg
        self._setup_projection(rho, fg, dxq)
        unorm = ufl.sqrt(ufl.dot(un, un) + 1e-30)

        # level set: Crank-Nicolson + SUPG with u^n
        if pr.two_phase:
            self.phi_n = compat.dolfinx.fem.Function(Q)
            f, w = ufl.TrialFunction(Q), ufl.TestFunction(Q)
            tau_l = 1.0 / ufl.sqrt((2.0 / dt) ** 2 + (2.0 * unorm / h) ** 2)
            wt = w + tau_l * ufl.dot(un, ufl.grad(w))
            fn = self.phi_n
            a_l = (f / dt + 0.5 * ufl.dot(un, ufl.grad(f))) * wt * dxq
            L_l = (fn / dt - 0.5 * ufl.dot(un, ufl.grad(fn))) * wt * dxq
            self.a_l, self.L_l = compat.form(a_l), compat.form(L_l)
            self.A_l = None
            self.b_l = compat.create_vector(self.L_l)
            self.ls_solver: fem.LinearSolver | None = None

        # velocity predictor
        v, w = ufl.TrialFunction(V), ufl.TestFunction(V)
        conv = ufl.dot(ufl.grad(v), un)
        a_m = (
            rho / dt * ufl.dot(v, w)
            + rho * ufl.dot(conv, w)
            + 2.0 * mu * ufl.inner(ufl.sym(ufl.grad(v)), ufl.sym(ufl.grad(w)))
        ) * dxq
        # incremental: -grad(p^n) in the predictor; total: the pressure step finds all of p
        p_n = self.p if pr.incremental else compat.dolfinx.fem.Constant(mesh, sc(0.0))
        L_m = (rho / dt * ufl.dot(un, w) + p_n * ufl.div(w)) * dxq
        if fg is not None:
            L_m = L_m + ufl.dot(fg, w) * dxq
        if supg:
            nu = mu / rho
            tau_m = 1.0 / ufl.sqrt(
                (2.0 / dt) ** 2 + (2.0 * unorm / h) ** 2 + 9.0 * (4.0 * nu / h**2) ** 2
            )
            ws = tau_m * ufl.dot(ufl.grad(w), un)
            a_m = a_m + ufl.dot(ws, rho * (v / dt + conv)) * dxq
            r_m = rho * un / dt - ufl.grad(p_n)
            L_m = L_m + ufl.dot(ws, r_m if fg is None else r_m + fg) * dxq
        self.a_m, self.L_m = compat.form(a_m), compat.form(L_m)
        self.A_m = None
        self.b_m = compat.create_vector(self.L_m)
        self.m_solver: fem.LinearSolver | None = None

        self._update_inflow(0.0)
        compat.set_bc(compat.petsc_vec(self.u), self._bcs_u)
        self.u.x.scatter_forward()
        if np.any(pr.gravity):
            self._initial_pressure()

    # -- pieces ---------------------------------------------------------------
    def _advect_levelset(self) -> None:
        t0 = time.perf_counter()
        self.phi_n.x.array[:] = self.phi.x.array
        self.A_l = fem.assemble_matrix(self.a_l, [], self.A_l)
        if self.ls_solver is None:
            self.ls_solver = fem.LinearSolver(self.A_l, "gmres", rtol=self.problem.rtol)
        else:
            self.ls_solver.set_operator(self.A_l)
        fem.assemble_vector(self.L_l, self.b_l)
        t1 = time.perf_counter()
        self.iterations["levelset"] = self.ls_solver.solve(self.b_l, compat.petsc_vec(self.phi))
        self.phi.x.scatter_forward()
        t2 = time.perf_counter()
        self.timings["assembly"] += t1 - t0
        self.timings["solve"] += t2 - t1
        pe = self.problem.reinit_every
        if pe and (self.steps_done + 1) % pe == 0:
            self.redistance()
            self.timings["reinit"] = self.timings.get("reinit", 0.0) + time.perf_counter() - t2
        self._update_phase()

    def step(self, t: float, dt: float) -> None:
        self.dt_c.value = dt
        self.dt_last = dt
        self.u_n.x.array[:] = self.u.x.array
        if self.problem.two_phase:
            self._advect_levelset()
        # predictor
        t0 = time.perf_counter()
        self._update_inflow(t + dt)
        self.A_m = fem.assemble_matrix(self.a_m, self._bcs_u, self.A_m)
        if self.m_solver is None:
            self.m_solver = fem.LinearSolver(self.A_m, "gmres", rtol=self.problem.rtol)
        else:
            self.m_solver.set_operator(self.A_m)
        fem.assemble_vector(self.L_m, self.b_m, self.a_m, self._bcs_u)
        t1 = time.perf_counter()
        self.iterations["momentum"] = self.m_solver.solve(self.b_m, compat.petsc_vec(self.u_star))
        self.u_star.x.scatter_forward()
        t2 = time.perf_counter()
        # pressure increment
        self._pressure_operator()
        t3 = time.perf_counter()
        self._solve_pressure(self.L_p, self.dp)
        t4 = time.perf_counter()
        # correction
        self._correct(dt)
        t5 = time.perf_counter()
        self.timings["assembly"] += (t1 - t0) + (t3 - t2) + (t5 - t4)
        self.timings["solve"] += t2 - t1
        self.steps_done += 1
        self._check()


def make_flow_solver(scene: Scene, domain: Domain) -> Solver:
    """The flow solver of the scene's frame."""
    frame = scene.frame
    if frame == "eulerian":
        return EulerianFlow(scene, domain)
    if frame == "lagrangian":
        from pfem2x.physics.flow_pfem2 import LagrangianFlow  # noqa: PLC0415

        return LagrangianFlow(scene, domain)
    raise SceneError(f"method.frame: the {frame!r} flow frame is not available yet")
