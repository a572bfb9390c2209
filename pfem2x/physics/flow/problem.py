"""The common flow problem: scene data, spaces, boundary conditions, phases, diagnostics.

:class:`FlowProblem` reads the scene's flow data; :class:`FlowSolver` is
what both flow frames (:mod:`pfem2x.physics.flow.eulerian`,
:mod:`pfem2x.physics.flow.pfem2`) share: the P1 velocity and pressure, the
box-side boundary conditions, the cell geometry of the diagnostics, the
interface geometry (:class:`~pfem2x.physics.flow.interface.InterfaceGeometry`)
and the small step API. Each frame adds its own parts (the pressure
projection of :mod:`pfem2x.physics.flow.projection`, a level set or a
particle cloud) and says how its phase volumes and cell densities are
measured.

Boundaries of a box domain, per side (``flow.left``, ``right``, ``bottom``,
``top``; ``flow.walls`` for the rest): ``slip`` (normal component zero),
``noslip``, ``inflow`` (``flow.inflow_velocity``) and ``outflow`` (do-nothing,
:math:`\\mu\\,\\partial u/\\partial n - p n = 0` with the viscous term in the gradient
form, :meth:`FlowProblem.viscous_form`; :math:`\\delta p = 0`).

Exact solutions (``flow.exact_velocity``, ``flow.exact_pressure``): the
diagnostics add ``velocity_l2_error`` / ``pressure_l2_error`` (domain RMS, the
pressure compared after removing its mean; :mod:`pfem2x.physics.flow.exact`),
and nothing is evaluated without them.

Time: the runner works in solver time ``t``; diagnostics also report
``tau = t * flow.time_factor`` (e.g. Tryggvason's units for Rayleigh–Taylor).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.cases import make_case
from pfem2x.compat import MPI, PETSc
from pfem2x.expr import Expression
from pfem2x.mesh import Domain, basis_gradients
from pfem2x.physics.base import Diverged, Solver, require_finite_input
from pfem2x.physics.flow._kernels import cell_velocity_kernel
from pfem2x.physics.flow.capillary import capillary_dt_limit
from pfem2x.physics.flow.exact import ExactFlowError
from pfem2x.physics.flow.interface import InterfaceGeometry
from pfem2x.scene import FLOW_SIDES, Scene, SceneError, check_components

__all__ = ["FlowProblem", "FlowSolver"]


#: flow.divergence_rtol = "auto": the discrete projection's tolerance for PFEM-2 with two
#: phases (the Rayleigh-Taylor, dam-break and rising-bubble scenes' value; docs/RESULTS.md,
#: "Dam break": without it the water particles lose 3-5 % at Courant 5)
AUTO_DIVERGENCE_RTOL = 0.05
#: flow.pass_pressure = "auto": the consistent pass pressure from this density ratio on (the
#: dam break at Courant 5 with the increment diverged at ratios 100 and above and ran at 33)
AUTO_CONSISTENT_RATIO = 10.0
#: flow.pressure_step = "auto": the level set's total pressure step from this density ratio
#: on (the dam break at Courant 1 with the increment dissipated 4 % of the released energy at
#: ratio 3 and 1 % at 4, gained 4.5 % at 5 and diverged from 8 on; PFEM-2: the increment)
AUTO_TOTAL_RATIO = 4.0


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
    exact_velocity, exact_pressure:
        Exact solution (component expressions, expression) or ``None``.
    """

    def __init__(self, scene: Scene, gdim: int):
        eff = scene.effects
        fl = scene.flow
        phases = []
        for name, ph in scene.phases.items():
            region = (
                Expression(ph.region, scene.params, f"phases.{name}.region")
                if ph.region is not None
                else None
            )
            mu = float(ph.viscosity) if eff.viscosity else 0.0
            phases.append((name, float(ph.density), mu, region))
        phases.sort(key=lambda p: p[3] is None)
        self.phases = phases
        self.two_phase = bool(eff.two_phase)
        g = np.zeros(gdim)
        if fl.gravity is not None:
            check_components("flow.gravity", fl.gravity, gdim)
        if eff.gravity:
            g[:] = fl.gravity
        self.gravity = g
        self.sides = {s: fl.side(s) for s in FLOW_SIDES[: 2 * gdim]}
        self.initial_velocity = (
            scene.vector_expr("flow", "initial_velocity", gdim)
            if fl.initial_velocity is not None
            else None
        )
        self.inflow_velocity = (
            scene.vector_expr("flow", "inflow_velocity", gdim)
            if fl.inflow_velocity is not None
            else None
        )
        self.exact_velocity = (
            scene.vector_expr("flow", "exact_velocity", gdim)
            if fl.exact_velocity is not None
            else None
        )
        self.exact_pressure = (
            scene.expr("flow", "exact_pressure") if fl.exact_pressure is not None else None
        )
        self.velocity_scale = scene.expr("flow", "velocity_scale").value()
        self.time_factor = scene.expr("flow", "time_factor").value()
        self.max_speed = scene.expr("flow", "max_speed").value()
        self.interface_width = float(fl.interface_width)
        self.reinit_every = int(fl.reinit_every)
        self.volume_correction = bool(fl.volume_correction)
        self.rtol = float(fl.rtol)
        self.correction = str(fl.correction)
        self.quadrature_degree = int(fl.quadrature_degree)
        #: surface tension coefficient (0 without effects.surface_tension: nothing assembled)
        self.surface_tension = (
            scene.expr("flow", "surface_tension").value() if eff.surface_tension else 0.0
        )
        #: whether a side is an ``outflow`` side
        self.outflow = "outflow" in self.sides.values()
        #: the viscous term in the gradient form mu grad(u):grad(w) (see :meth:`viscous_form`)
        self.gradient_form = self.outflow and len({p[2] for p in phases}) == 1
        self._frame_defaults(scene)

    def _frame_defaults(self, scene: Scene) -> None:
        """The keys whose ``"auto"`` the frame, the phases and the walls decide."""
        fl = scene.flow
        #: what each ``"auto"`` key of the frame defaults resolved to (summary.json)
        self.auto: dict[str, Any] = {}
        #: flow.pressure_step: "increment" or "total" (the level set's at large ratios)
        self.pressure_step = self._auto(
            "flow.pressure_step",
            fl.pressure_step,
            "total"
            if scene.frame == "eulerian" and self.density_ratio >= AUTO_TOTAL_RATIO
            else "increment",
        )
        self.incremental = self.pressure_step == "increment"
        #: flow.divergence_rtol: > 0, the discrete projection (:mod:`.projection`)
        self.divergence_rtol = self._auto(
            "flow.divergence_rtol",
            fl.divergence_rtol,
            AUTO_DIVERGENCE_RTOL
            if scene.frame == "lagrangian"
            and self.two_phase
            and not self.outflow
            and self.correction == "velocity"
            else 0.0,
        )
        #: flow.divergence_preconditioner: the discrete projection's ("pressure", "jacobi")
        self.divergence_preconditioner = str(fl.divergence_preconditioner)
        #: flow.pass_pressure (PFEM-2): "increment" or "consistent" (recorded where read)
        self.pass_pressure = self._auto(
            "flow.pass_pressure",
            fl.pass_pressure,
            "consistent" if self.density_ratio >= AUTO_CONSISTENT_RATIO else "increment",
            record=scene.frame == "lagrangian"
            and bool(fl.extra_pass)
            and self.incremental
            and fl.explicit_pressure == "consistent",
        )

    @property
    def density_ratio(self) -> float:
        """The largest phase density over the smallest (1 with one phase)."""
        rho = [p[1] for p in self.phases] if self.two_phase else [1.0]
        return max(rho) / min(rho) if min(rho) > 0.0 else float("inf")

    def _auto(self, key: str, value: Any, choice: Any, record: bool = True) -> Any:
        """``value``, or ``choice`` when it is ``"auto"`` (then in :attr:`auto` if ``record``)."""
        if value != "auto":
            return float(value) if isinstance(value, int | float) else value
        if record:
            self.auto[key] = choice
        return choice

    def viscous_form(self, mu: Any, v: Any, w: Any) -> Any:
        """The viscous term's integrand for trial ``v`` and test ``w``.

        ``2 mu eps(v):eps(w)`` (the stress of any viscosity field), except with an
        ``outflow`` side and one viscosity: ``mu grad(v):grad(w)``. For a
        divergence-free velocity and constant ``mu`` the two have the same operator
        inside, but their natural condition on the outflow side differs: the
        gradient form's ``mu du/dn - p n = 0`` (the "do-nothing" condition of
        Heywood, Rannacher & Turek 1996) holds for a developed channel flow, the
        symmetric one's ``2 mu eps(u) n - p n = 0`` does not (it asks
        ``dv/dx = -du/dy`` there and bends the flow at the outlet).
        """
        if self.gradient_form:
            return mu * ufl.inner(ufl.grad(v), ufl.grad(w))
        return 2.0 * mu * ufl.inner(ufl.sym(ufl.grad(v)), ufl.sym(ufl.grad(w)))


class FlowSolver(Solver):
    """Spaces, fields, boundary conditions and diagnostics shared by the flow frames.

    A frame sets up its own parts after this constructor, then measures
    ``volume0`` (the phase volumes at the start) once with
    :meth:`phase_volumes`. It implements :meth:`phase_volumes` and
    :meth:`cell_density` (what its density is made of) and :meth:`step`.
    """

    #: the frame's capillary force (:mod:`pfem2x.physics.flow.capillary`; None without
    #: effects.surface_tension)
    capillary: Any = None
    checkpoint_state = ("u", "p", "phi", "phase", "u_star", "dp", "dt_last", "steps_done",
                        "volume0")  # fmt: skip

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        if domain.gdim != 2:  # a gmsh file's dimension is known once it is meshed
            raise SceneError(
                f"mesh.file: flow is available on 2D meshes only (for now), "
                f"the file's mesh is {domain.gdim}D"
            )
        self.problem = pr = FlowProblem(scene, domain.gdim)
        self.auto_keys.update(pr.auto)
        if pr.divergence_rtol > 0.0 and (pr.outflow or pr.correction != "velocity"):
            raise SceneError(
                "flow.divergence_rtol: the discrete projection needs closed walls (no outflow "
                'side) and flow.correction = "velocity"'
            )
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
            n = self.Q.dofmap.index_map.size_local
            require_finite_input(
                self.comm, "flow.initial_velocity", arr[:n], self.coords[:n, :gdim]
            )
        self.H = domain.min_h()
        self.eps = pr.interface_width * self.H
        tab = domain.table
        self.n_owned = tab.num_cells_owned
        self.dofmap = compat.dofmap_array(self.Q)[: tab.num_cells]
        self.cell_xy = self.coords[self.dofmap[: self.n_owned]][:, :, :gdim]
        self.cell_vol = tab.volume[: self.n_owned]
        # gradients of the barycentric coordinates (for div u), ordered like the dofmap
        self._gradlam = basis_gradients(tab)
        self._hcell = tab.h_edge[: self.n_owned]
        self._volume = float(self.comm.allreduce(float(self.cell_vol.sum()), op=MPI.SUM))
        #: errors against the exact solution (``None`` without one: nothing is evaluated)
        self.exact: ExactFlowError | None = None
        if pr.exact_velocity is not None or pr.exact_pressure is not None:
            self.exact = ExactFlowError(
                self.comm, self.cell_xy, self.cell_vol, self.dofmap[: self.n_owned],
                pr.exact_velocity, pr.exact_pressure,
            )  # fmt: skip
        # -g.x at the cell centroids: potential energy = sum rho_K |K| (-g.x_K) (exact for DG0 rho)
        g = pr.gravity[:gdim]
        self._gravity_height = -(self.cell_xy.mean(axis=1) @ g) if np.any(g) else None
        self.interface = InterfaceGeometry(
            self.comm, self.coords, self.dofmap, self.n_owned, self.eps
        )
        #: two phases: the phase indicator (1 in the phase with a region) and a level set
        #: whose zero iso-line is the interface (both P1)
        self.phi: Any = None
        self.phase: Any = None
        if pr.two_phase:
            self.phi = compat.dolfinx.fem.Function(self.Q, name="phi")
            self.phase = compat.dolfinx.fem.Function(self.Q, name="phase")
        self.dt_last = 0.0
        self.steps_done = 0
        self._bcs_u, self._bcs_p, self._inflow = self._boundary_conditions()
        #: phase volumes at the start (set by the frame once its phases are known)
        self.volume0: dict[str, float] = {}
        self.case = make_case(scene.scene.case, self)  # scene.case diagnostics
        #: the pressure step (a frame creates it once its density is known)
        self.projection: Any = None
        self.u_star: Any = None
        self.dp: Any = None

    def _use_projection(self, projection: Any) -> None:
        """Adopt the frame's :class:`PressureProjection` (its ``u_star``, ``dp`` are state)."""
        self.projection = projection
        self.u_star = projection.u_star
        self.dp = projection.dp

    # -- boundaries -----------------------------------------------------------
    def _boundary_conditions(self) -> tuple[list, list, Any]:
        pr = self.problem
        lo, hi = self.domain.bounds
        tol = 1e-8 * float(np.max(hi - lo))
        mesh = self.domain.mesh
        bcs_u, bcs_p = [], []
        inflow = None
        #: the nodes of the inflow sides (where flow.inflow_velocity is used)
        self._inflow_nodes = np.zeros(0, dtype=np.int32)
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
                    nodes = compat.dolfinx.fem.locate_dofs_topological(
                        self.Q, mesh.topology.dim - 1, facets
                    )
                    self._inflow_nodes = np.union1d(self._inflow_nodes, nodes)
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
        self._inflow.x.array.reshape(-1, self.gdim)[:] = self.inflow_at(self.coords, t)

    def inflow_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """``flow.inflow_velocity`` at the points ``x`` (rows of 3 coordinates) and time
        ``t``, shape ``(len(x), gdim)``."""
        exprs = self.problem.inflow_velocity
        return np.stack([np.broadcast_to(e(x, t), len(x)) for e in exprs], axis=1)

    def _owned_inflow_nodes(self) -> np.ndarray:
        """This rank's owned nodes of the inflow sides."""
        return self._inflow_nodes[self._inflow_nodes < self.Q.dofmap.index_map.size_local]

    def _require_finite_inflow(self) -> None:
        """SceneError if ``flow.inflow_velocity`` is not finite on the inflow sides at t = 0.

        Only the sides' own nodes count (the expression is evaluated everywhere but used
        there). Collective.
        """
        if self._inflow is None:
            return
        nodes = self._owned_inflow_nodes()
        arr = self._inflow.x.array.reshape(-1, self.gdim)
        require_finite_input(
            self.comm,
            "flow.inflow_velocity",
            arr[nodes],
            self.coords[nodes, : self.gdim],
            where="the inflow sides",
        )

    def input_report(self, t0: float, t1: float) -> str:
        """``flow.inflow_velocity`` (the flow's one expression of t) if it is not finite
        on the inflow sides' owned nodes at ``t0``, the step's middle or ``t1``
        (collective): ``"flow.inflow_velocity is not finite at 17 node(s) at t = 0.5"``,
        or ``""``."""
        if self._inflow is None:
            return ""
        x = self.coords[self._owned_inflow_nodes()]
        times = (t0, 0.5 * (t0 + t1), t1)
        bad = np.zeros(len(times))
        with np.errstate(all="ignore"):
            for j, t in enumerate(times):
                v = self.inflow_at(x, t)
                bad[j] = np.count_nonzero(~np.all(np.isfinite(v), axis=1))
        bad = self.comm.allreduce(bad, op=MPI.SUM)
        j = next((j for j in range(len(times)) if bad[j] > 0), None)
        if j is None:
            return ""
        return f"flow.inflow_velocity is not finite at {int(bad[j])} node(s) at t = {times[j]:.6g}"

    # -- what a frame measures ------------------------------------------------
    def phase_volumes(self) -> dict[str, float]:
        """Volume of each phase, by name (global)."""
        raise NotImplementedError

    def cell_density(self) -> np.ndarray:
        """Density of each owned cell (kinetic and potential energy)."""
        raise NotImplementedError

    # -- diagnostics ----------------------------------------------------------
    def interfaces(self) -> np.ndarray | None:
        """This rank's segments ``(m, 2, 2)`` of the interface (zero iso-line of ``phi``)."""
        if self.phi is None:
            return None
        return self.interface.segments(self.phi.x.array)

    def interface_function(self) -> np.ndarray:
        """Nodal values (owned and ghost) of the P1 function whose zero iso-line is the interface.

        The level set ``phi`` here; a frame with another interface function
        (PFEM-2: the particles' projected signed distance) overrides it.
        """
        return self.phi.x.array

    def tips(self) -> tuple[float, float]:
        """Lowest and highest y of the zero iso-line of the level set (global)."""
        return self.interface.tips(self.phi.x.array)

    def diagnostics(self, t: float) -> dict[str, float]:
        comm = self.comm
        u = self.u.x.array.reshape(-1, self.gdim)
        dofs = self.dofmap[: self.n_owned]  # (n, nv)
        # per cell in one compiled pass: div u, the largest vertex speed, and
        # int_K |u|^2 = |K| / (d+1)(d+2) (sum_i |u_i|^2 + |sum_i u_i|^2), exact for P1 u
        div, speed_c, sq, tot = cell_velocity_kernel(u, dofs, self._gradlam)
        rho_c = self.cell_density()
        nv = dofs.shape[1]
        u2 = (sq + tot) / (nv * (nv + 1))
        ke = 0.5 * np.sum(rho_c * u2 * self.cell_vol)
        div2 = float(comm.allreduce(float(np.dot(self.cell_vol, div**2)), op=MPI.SUM))
        d = {
            "tau": t * self.problem.time_factor,
            "kinetic_energy": float(comm.allreduce(ke, op=MPI.SUM)),
            "div_max": float(comm.allreduce(np.abs(div).max() if len(div) else 0.0, op=MPI.MAX)),
            # domain RMS of the (cell-wise constant) divergence
            "div_rms": float(np.sqrt(div2 / self._volume)),
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
        for name, v in self.phase_volumes().items():
            d[f"volume_{name}"] = v
            v0 = self.volume0.get(name, v)
            d[f"volume_change_{name}"] = (v - v0) / v0 if v0 else 0.0
        if self.problem.two_phase:
            d["tip_falling"], d["tip_rising"] = self.tips()
        if self.capillary is not None:  # the step against the explicit capillary limit
            d["capillary_dt_ratio"] = self.dt_last / self.capillary_dt_limit()
            # the share of the segments whose curvature is not the distance fit's
            cap = self.capillary
            d["curvature_fallback"] = cap.fallback_segments / max(cap.segment_count, 1)
        if self.exact is not None:
            d.update(self.exact.diagnostics(u, self.p.x.array, t))
        if self.problem.divergence_rtol > 0.0:  # the last step's discrete projection
            d["divergence_iterations"] = float(self.projection.iterations.get("discrete", 0))
        d.update(self.case.diagnostics(self, t))
        return d

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        if not history:
            return {}
        out: dict[str, Any] = {
            "kinetic_energy_final": history[-1]["kinetic_energy"],
            "div_max": max(h["div_max"] for h in history),
            "div_rms_max": max(h.get("div_rms", 0.0) for h in history),
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
            if released[-1] > 0.0:  # what did not become kinetic energy: dissipated
                gained = history[-1]["kinetic_energy"] - history[0]["kinetic_energy"]
                out["energy_lost_final"] = 1.0 - gained / released[-1]
        for name, *_ in self.problem.phases:
            out[f"volume_{name}"] = [history[0][f"volume_{name}"], history[-1][f"volume_{name}"]]
            out[f"volume_change_{name}"] = history[-1][f"volume_change_{name}"]
            out[f"volume_change_max_{name}"] = max(abs(h[f"volume_change_{name}"]) for h in history)
        if self.problem.two_phase:
            out["tip_falling"] = [[h["tau"], h["tip_falling"]] for h in history]
            out["tip_rising"] = [[h["tau"], h["tip_rising"]] for h in history]
        if self.capillary is not None:
            lim = self.capillary_dt_limit()
            out["capillary_dt_limit"] = lim
            out["capillary_dt_ratio_max"] = max(h.get("capillary_dt_ratio", 0.0) for h in history)
            fb = [h.get("curvature_fallback", 0.0) for h in history]
            out["curvature_fallback_mean"] = float(np.mean(fb))
            out["curvature_fallback_max"] = max(fb)
        out["tau_factor"] = self.problem.time_factor
        out.update(ExactFlowError.metrics(history))
        out.update(self.case.metrics(history))
        return out

    def capillary_dt_limit(self) -> float:
        """The explicit capillary step limit of the mesh (shortest edge) and the two phases."""
        ph = self.problem.phases
        return capillary_dt_limit(ph[0][1], ph[1][1], self.H, self.problem.surface_tension)

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
        """Every field finite and the speed within ``flow.max_speed`` (collective)."""
        self.check_finite(0.0)
        if self.problem.max_speed > 0:
            vmax = self.max_velocity(0.0)
            if vmax > self.problem.max_speed:
                raise Diverged(
                    f"speed {vmax:.3g} exceeds flow.max_speed = {self.problem.max_speed:.3g}"
                )
