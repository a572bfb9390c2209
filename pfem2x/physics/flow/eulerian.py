r"""The level-set flow frame (``method.frame = "eulerian"``), the paper's baseline.

.. math::
    \rho(\partial_t u + u\cdot\nabla u) = -\nabla p + \nabla\cdot(2\mu\,\varepsilon(u)) + \rho g,
    \qquad \nabla\cdot u = 0.

One step:

1. level set :math:`\phi` (> 0 in the phase that has a ``region``): Crank–Nicolson
   + SUPG with the velocity :math:`u^n`, then geometric re-distancing every
   ``flow.reinit_every`` steps (signed distance to the P1 zero iso-line, which
   is kept; values clipped at :math:`\pm 8\varepsilon`; with surface tension
   the nodes within :math:`\varepsilon + H` get the distance to the circles the
   curvature fit found, :meth:`.capillary.CapillaryForce.redistance`, and
   :math:`\phi` starts as the distance to the region's boundary sampled below
   H, :func:`.curvature.region_distance`);
2. :math:`\rho, \mu` from :math:`\phi^{n+1}` with a smoothed Heaviside of
   half-width :math:`\varepsilon` = ``flow.interface_width`` · H (H: shortest edge);
3. velocity predictor (incremental pressure-correction, Guermond–Quartapelle):
   :math:`\rho(\tilde u - u^n)/\Delta t + \rho\,u^n\cdot\nabla\tilde u
   - \nabla\cdot(2\mu\varepsilon(\tilde u)) = -\nabla p^n + \rho g`, SUPG on the
   convective term (``method.supg``), semi-implicit (Oseen) linearisation;
4. pressure increment and 5. correction: :mod:`pfem2x.physics.flow.projection`.

Two phases with gravity: :math:`\rho g` is the balanced force of
:mod:`pfem2x.physics.flow.balanced` (built on the zero iso-line of
:math:`\phi`), in the predictor with ``flow.pressure_step = "increment"`` and
in the pressure step with ``"total"`` (the default, ``"auto"``, from a density ratio of
4 on: the increment gains energy from 5 on); the level-set solve starts from
:math:`\phi^n`. A flat interface inside cells stays at rest to solver tolerance.

Equal-order P1/P1 is stabilised only by the splitting (the pressure Laplacian
of step 4 acts like a PSPG term of size :math:`\Delta t`); no extra pressure
stabilisation is added.

Scene keys this frame reads (besides the problem's: ``flow.gravity``, the
sides, ``initial_velocity``, ``inflow_velocity``, ``velocity_scale``,
``time_factor``, ``max_speed``, ``[phases]``):

=============================  ==========================================================
key                            effect in this frame
=============================  ==========================================================
``method.supg``                SUPG on the predictor's convective term
``method.preconditioner``      pressure solve (cg); the predictor and level set use GMRES/ILU
``flow.interface_width``       smoothed Heaviside half-width / H (density, viscosity)
``flow.reinit_every``          re-distancing every N steps (0: never)
``flow.volume_correction``     after re-distancing: shift phi to the initial volume
``flow.surface_tension``       surface tension (:mod:`pfem2x.physics.flow.capillary`)
``flow.capillary_increment``   surface tension: the forces' increment through the predictor
``flow.capillary_damping``     surface tension: the implicit term of the whole or normal velocity
``flow.pressure_step``         ``increment``: :math:`-\nabla p^n` in the predictor; ``total``
``flow.correction``            ``velocity`` (:math:`M^{-1}\rho^{-1}`) or ``momentum``
``flow.rtol``                  tolerance of every linear solve
``flow.quadrature_degree``     quadrature of all flow forms
=============================  ==========================================================

Ignored here: ``method.theta`` (Crank–Nicolson level set, implicit predictor), the
particle keys and the PFEM-2 ``flow.*`` keys.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem
from pfem2x.compat import PETSc
from pfem2x.mesh import Domain
from pfem2x.physics.flow.balanced import JumpForce
from pfem2x.physics.flow.capillary import CapillaryForce, capillary_increment, region_distance
from pfem2x.physics.flow.interface import InterfaceGeometry
from pfem2x.physics.flow.problem import FlowSolver
from pfem2x.physics.flow.projection import PressureProjection
from pfem2x.scene import Scene

__all__ = ["EulerianFlow"]


class EulerianFlow(FlowSolver):
    """Fractional-step P1/P1 NS with SUPG and a SUPG level set (see the module docstring)."""

    name = "flow-eulerian"
    checkpoint_state = ("u_n", "phi_n")

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        pr = self.problem
        mesh = domain.mesh
        sc = PETSc.ScalarType
        if pr.two_phase:
            self._keep = compat.dolfinx.fem.Function(self.Q)  # re-distancing: frozen nodes
            region = pr.phases[0][3]
            self.phi.x.array[:] = self.interface.signed_distance(region)
            if pr.surface_tension > 0.0:  # the curvature fit's samples: distances below h
                self.phi.x.array[:] = region_distance(self.interface, region)
            self._update_phase()
        self.dt_c = compat.dolfinx.fem.Constant(mesh, sc(1.0))
        self._eps_c = compat.dolfinx.fem.Constant(mesh, sc(self.eps))
        # the smoothed Heaviside (sin) and SUPG (sqrt) would make UFL pick very high degrees
        dxq = ufl.dx(domain=mesh, metadata={"quadrature_degree": pr.quadrature_degree})
        self.u_n = compat.dolfinx.fem.Function(self.V)
        g = compat.dolfinx.fem.Constant(mesh, np.asarray(pr.gravity, dtype=sc))
        (_, r1, m1, _) = pr.phases[0]
        if pr.two_phase:
            (_, r2, m2, _) = pr.phases[1]
            H = InterfaceGeometry.heaviside(self.phi, self._eps_c)
            rho = r2 + (r1 - r2) * H
            mu = m2 + (m1 - m2) * H
        else:
            rho = compat.dolfinx.fem.Constant(mesh, sc(r1))
            mu = compat.dolfinx.fem.Constant(mesh, sc(m1))
        self._rho = rho
        # Gravity with the full pressure. One phase: rho g. Two phases: the balanced
        # force of pfem2x.physics.flow.balanced (rho g plus a jump force on the cells
        # next to the interface; a flat interface at rest stays at rest to round-off).
        # (The interFoam-style p_rgh form, force -(g.x) grad rho with the smoothed rho,
        # was tried: twice the spurious wall currents of rho g.)
        #: the balanced two-phase body force (None with one phase or without gravity)
        self.jump: JumpForce | None = None
        if pr.two_phase and np.any(pr.gravity):
            # band: every cell the smoothed density varies on has all its nodes in it
            self.jump = JumpForce(
                self.Q, self.interface, r1, r2, pr.gravity[: self.gdim], self.eps + 2.0 * self.H
            )
            self.jump.update(self.phi.x.array)
            fg = self.jump.force(rho, g)
        else:
            fg = rho * g if np.any(pr.gravity) else None  # no body force without gravity
        # surface tension: the balanced capillary force (pfem2x.physics.flow.capillary)
        # on the zero iso-line of phi, weighted by the smoothed Heaviside
        #: the capillary force (None without effects.surface_tension)
        self.capillary: CapillaryForce | None = None
        if pr.two_phase and pr.surface_tension > 0.0:
            self.capillary = CapillaryForce(
                self.Q, self.interface, pr.surface_tension, self.eps + 2.0 * self.H, self.H,
                damping=scene.flow.capillary_damping,
            )  # fmt: skip
            self.capillary.update(self.phi.x.array, self.cell_vol)
            fc = self.capillary.force(H)
            fg = fc if fg is None else fg + fc
        self._f_grav = fg
        self._use_projection(
            PressureProjection(
                self.V, self.Q, self.gdim, rho, fg, dxq, self.dt_c, self._bcs_u, self._bcs_p,
                pr.correction, pr.incremental, scene.method.preconditioner, pr.rtol,
                self.timer,
                force_in_projection=(self.jump is not None or self.capillary is not None)
                and not pr.incremental, divergence_rtol=pr.divergence_rtol,
                divergence_preconditioner=pr.divergence_preconditioner,
            )
        )  # fmt: skip
        if self.projection.force_in_projection:
            fg = None  # the pressure step has the body force, the predictor none
        self.phi_n: Any = None
        if pr.two_phase:
            self._levelset_forms(dxq)
        self._momentum_forms(rho, mu, fg, dxq)
        self._update_inflow(0.0)
        self._require_finite_inflow()
        compat.set_bc(compat.petsc_vec(self.u), self._bcs_u)
        self.u.x.scatter_forward()
        if np.any(pr.gravity) or self.capillary is not None:
            self.projection.initial_pressure(self.p)
        self.volume0 = self.phase_volumes()

    def _unorm(self) -> Any:
        un = self.u_n
        return ufl.sqrt(ufl.dot(un, un) + 1e-30)

    def _levelset_forms(self, dxq: Any) -> None:
        """Crank–Nicolson + SUPG transport of the level set with ``u^n``."""
        Q, un, dt = self.Q, self.u_n, self.dt_c
        h = ufl.CellDiameter(self.domain.mesh)
        self.phi_n = compat.dolfinx.fem.Function(Q)
        f, w = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        tau_l = 1.0 / ufl.sqrt((2.0 / dt) ** 2 + (2.0 * self._unorm() / h) ** 2)
        wt = w + tau_l * ufl.dot(un, ufl.grad(w))
        fn = self.phi_n
        a_l = (f / dt + 0.5 * ufl.dot(un, ufl.grad(f))) * wt * dxq
        L_l = (fn / dt - 0.5 * ufl.dot(un, ufl.grad(fn))) * wt * dxq
        self.a_l, self.L_l = compat.form(a_l), compat.form(L_l)
        self.A_l: Any = None
        self.b_l = compat.create_vector(self.L_l)
        self.ls_solver: fem.LinearSolver | None = None

    def _momentum_forms(self, rho: Any, mu: Any, fg: Any, dxq: Any) -> None:
        """The velocity predictor (Oseen, optionally SUPG)."""
        pr, mesh, V, un, dt = self.problem, self.domain.mesh, self.V, self.u_n, self.dt_c
        h = ufl.CellDiameter(mesh)
        v, w = ufl.TrialFunction(V), ufl.TestFunction(V)
        conv = ufl.dot(ufl.grad(v), un)
        a_m = (rho / dt * ufl.dot(v, w) + rho * ufl.dot(conv, w) + pr.viscous_form(mu, v, w)) * dxq
        # incremental: -grad(p^n) in the predictor; total: the pressure step finds all of p
        p_n = self.p if pr.incremental else compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(0))
        L_m = (rho / dt * ufl.dot(un, w) + p_n * ufl.div(w)) * dxq
        if fg is not None:
            L_m = L_m + ufl.dot(fg, w) * dxq
        if self.capillary is not None:  # the semi-implicit Laplace-Beltrami term
            a_m = a_m + self.capillary.implicit_form(v, w, dt) * dxq
        if self.scene.method.supg:
            unorm = self._unorm()
            nu = mu / rho
            tau_m = 1.0 / ufl.sqrt(
                (2.0 / dt) ** 2 + (2.0 * unorm / h) ** 2 + 9.0 * (4.0 * nu / h**2) ** 2
            )
            ws = tau_m * ufl.dot(ufl.grad(w), un)
            a_m = a_m + ufl.dot(ws, rho * (v / dt + conv)) * dxq
            r_m = rho * un / dt - ufl.grad(p_n)
            L_m = L_m + ufl.dot(ws, r_m if fg is None else r_m + fg) * dxq
        self.a_m, self.L_m = compat.form(a_m), compat.form(L_m)
        #: flow.capillary_increment: the mass matrix of the force's increment
        self.a_mass: Any = None
        if self.capillary is not None and self.scene.flow.capillary_increment:
            self.a_mass = compat.form(rho / dt * ufl.dot(v, w) * dxq)
        self.M_cap: Any = None
        self.A_m: Any = None
        self.b_m = compat.create_vector(self.L_m)
        self.m_solver: fem.LinearSolver | None = None

    # -- phases -----------------------------------------------------------------
    def _update_phase(self) -> None:
        self.phase.x.array[:] = self.interface.heaviside_nodes(self.phi.x.array)

    def redistance(self) -> None:
        """Geometric re-distancing: signed distance to the current zero iso-line (clipped)."""
        self.interface.redistance(self.phi, self._keep)

    def _correct_volume(self) -> None:
        """Shift phi by a constant: phase 1 gets its initial volume back (collective).

        The shift is the volume defect over the interface length (a uniform
        normal displacement of a signed distance), applied twice.
        """
        itf, arr = self.interface, self.phi.x.array
        v0 = self.volume0[self.problem.phases[0][0]]
        for _ in range(2):
            segs = itf.segments(arr)
            length = np.sum(np.linalg.norm(segs[:, 1] - segs[:, 0], axis=1)) if len(segs) else 0.0
            length = float(self.comm.allreduce(length, op=compat.MPI.SUM))
            if length <= 0.0:
                return
            arr += (v0 - itf.positive_volume(arr, self.cell_vol)) / length

    def phase_volumes(self) -> dict[str, float]:
        names = [p[0] for p in self.problem.phases]
        total = float(self.comm.allreduce(self.cell_vol.sum(), op=compat.MPI.SUM))
        if not self.problem.two_phase:
            return {names[0]: total}
        v1 = self.interface.positive_volume(self.phi.x.array, self.cell_vol)
        return {names[0]: v1, names[1]: total - v1}

    def _nodal_density(self) -> np.ndarray:
        ph = self.problem.phases
        if not self.problem.two_phase:
            return np.full(len(self.coords), ph[0][1])
        h = self.phase.x.array
        return ph[1][1] + (ph[0][1] - ph[1][1]) * h

    def cell_density(self) -> np.ndarray:
        """Density of each owned cell: the mean of its nodal densities."""
        return self._nodal_density()[self.dofmap[: self.n_owned]].mean(axis=1)

    # -- the step ---------------------------------------------------------------
    def _advect_levelset(self) -> None:
        with self.timer("assembly"):
            self.phi_n.x.array[:] = self.phi.x.array
            self.A_l = fem.assemble_matrix(self.a_l, [], self.A_l)
            if self.ls_solver is None:
                self.ls_solver = fem.LinearSolver(self.A_l, "gmres", rtol=self.problem.rtol)
                if self.jump is not None or self.capillary is not None:  # start from phi^n: rest
                    self.ls_solver.ksp.setInitialGuessNonzero(True)
            else:
                self.ls_solver.set_operator(self.A_l)
            fem.assemble_vector(self.L_l, self.b_l)
        with self.timer("solve"):
            self.projection.iterations["levelset"] = self.ls_solver.solve(
                self.b_l, compat.petsc_vec(self.phi)
            )
            self.phi.x.scatter_forward()
        pe = self.problem.reinit_every
        reinit = bool(pe and (self.steps_done + 1) % pe == 0)
        if reinit:
            with self.timer("reinit"):
                self.redistance()
                if self.problem.volume_correction:
                    self._correct_volume()
        if self.capillary is not None:
            self.capillary.update(self.phi.x.array, self.cell_vol)
            if reinit:  # near the interface: the distance to the fitted circles
                self.capillary.redistance(self.phi.x.array, self.eps + self.H)
        self._update_phase()
        if self.jump is not None:
            self.jump.update(self.phi.x.array)

    def _predict(self, t: float, dt: float) -> None:
        with self.timer("assembly"):
            self._update_inflow(t + dt)
            self.A_m = fem.assemble_matrix(self.a_m, self._bcs_u, self.A_m)
            if self.m_solver is None:
                self.m_solver = fem.LinearSolver(self.A_m, "gmres", rtol=self.problem.rtol)
            else:
                self.m_solver.set_operator(self.A_m)
            fem.assemble_vector(self.L_m, self.b_m, self.a_m, self._bcs_u)
        with self.timer("solve"):
            self.projection.iterations["momentum"] = self.m_solver.solve(
                self.b_m, compat.petsc_vec(self.u_star)
            )
            self.u_star.x.scatter_forward()

    def _capillary_increment(self, dt: float) -> None:
        """``flow.capillary_increment`` (:func:`.capillary.capillary_increment`).

        Without, the capillary waves bound the step: the level set at Courant 1,
        h = 1/40 (13 x the explicit limit) had a minimum circularity of 0.77.
        """
        proj = self.projection
        with self.timer("assembly"):
            self.M_cap = fem.assemble_matrix(self.a_mass, self._bcs_u, self.M_cap)

        def project() -> None:
            proj.solve_increment()
            proj.correct(self.u, self.p, dt)

        capillary_increment(self.u, self.u_star, self.m_solver, self.M_cap.mult, project)

    def step(self, t: float, dt: float) -> None:
        self.dt_c.value = dt
        self.dt_last = dt
        self.u_n.x.array[:] = self.u.x.array
        if self.problem.two_phase:
            self._advect_levelset()
        self._predict(t, dt)
        with self.timer("assembly"):
            self.projection.assemble_operator()
        self.projection.solve_increment()
        with self.timer("assembly"):
            self.projection.correct(self.u, self.p, dt)
        if self.a_mass is not None:
            self._capillary_increment(dt)
        self.steps_done += 1
        self._check()
