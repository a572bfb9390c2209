r"""PFEM-2 Navier–Stokes, one or two phases: ``method.frame = "lagrangian"``.

Particles carry the velocity ``u`` and, with two phases, a sharp ``phase``
(1 in the phase that has a ``region``, 0 in the other). The fixed P1 mesh only
sees what the particles project onto it; convection is done by the particle
motion alone (no convective term is ever assembled). One step
(paper section 3, steps 1–5, first order in the linearisation, :math:`\theta = 0`):

1. **Move** every particle along the streamline of :math:`u^n` (X-IVAS,
   eq. 2.10 with :math:`\theta = 0`, RK2 sub-steps of at most
   ``method.substep_courant`` cells) and add the explicit part of the
   momentum source, :math:`a^n = g - \rho^{-1}\nabla p^n`, integrated along
   the path (eq. 2.9) inside the move: the trapezoid rule on each of its
   sub-steps (the same limits ``method.substep_courant``,
   ``method.substep_gradient``), so a particle's centripetal acceleration
   follows its curved path; one call of the numba move kernel per pass
   (:func:`pfem2x.particles.advect` with a vector source).
   :math:`a^n` is the P1 field :math:`M_\rho^{-1}\int(\rho g - \nabla p^n)\cdot w`
   (the :math:`\rho`-weighted lumped mass of the correction step), so a fluid
   in hydrostatic balance gets no kick and the particles get no cell-wise jumps.
   Its pressure (``flow.explicit_pressure = "consistent"``) is solved from
   :math:`u^n` at the start of the step,
   :math:`\nabla\cdot(\rho^{-1}\nabla p^n) = \nabla\cdot(\rho^{-1}f) - \nabla u^n : (\nabla u^n)^T`
   (the pressure of a divergence-free velocity; hydrostatic at rest; with one
   viscous phase the right-hand side also has :math:`\nu\Delta u^n = -\nu\nabla\times\omega_h`,
   :mod:`.vorticity`, whose boundary terms give a channel its :math:`dp/dx = \mu u''`), instead of
   the last step's :math:`p^n` (``"lagged"``), which starts from 0 and, the
   pressure step correcting only the divergence, does not follow a decaying
   vortex: Taylor–Green at Courant 8 (32 × 32) 0.0036 against 0.042
   (docs/RESULTS.md).
2. **Project** :math:`\hat u_p` to the P1 nodes (``method.projection``; ``"auto"``
   is the paper's shape-function average: the linear-exact fit passes the
   FLIP velocity's sub-cell noise on to the mesh, and Rayleigh–Taylor at
   100 × 400 diverged with it at Courant 4 by τ = 2.3; the fit with an outflow side) →
   :math:`\hat u`. The density and viscosity are cell-wise constants (DG0)
   from each cell's phase-1 fraction: sharp within one cell, no smoothing
   band. With gravity (two phases) and ``flow.density = "level_set"`` (the
   default; ``"particles"``: the fraction of the cell's particles in phase 1)
   the fraction is the cut-cell area where
   the P1 level set ``dist`` is positive (below), the interface of the
   balanced force, and ``dist`` is first shifted by one constant so that
   area keeps its initial value (:meth:`LagrangianFlow._conserve_volume`;
   the P1 velocity is divergence-free only weakly, and the particles' own
   phase volume drifted by 0.17 % on Rayleigh–Taylor 100 × 400 at Courant 8,
   1.2 % on 16 × 64); without gravity it is the fraction of each cell's
   particles with ``phase = 1``. The phase is also projected to P1
   (``"average"``, bounded) for output, the interface tips and ``phi =
   phase - 1/2``.
3. **Implicit mesh step** (incremental pressure correction):
   viscous predictor :math:`M_\rho(u^* - \hat u)/\Delta t + K_\mu u^* = 0`
   (lumped :math:`\rho`-mass, :math:`K_\mu` the :math:`2\mu\,\varepsilon:\varepsilon`
   stiffness with the wall conditions, assembled once when :math:`\mu` is
   the same in both phases, else every step; skipped without viscosity),
   pressure increment :math:`\nabla\cdot(\rho^{-1}\nabla\delta p) =
   \nabla\cdot u^*/\Delta t` (operator re-assembled every step: :math:`\rho`
   moves with the particles), correction :math:`u^{n+1} = u^* - \Delta t
   M^{-1}\int\rho^{-1}\nabla\delta p\cdot w` (``flow.correction =
   "velocity"``: the same :math:`1/\rho` as the pressure equation; the
   :math:`\rho`-weighted lumped mass, ``"momentum"``, lost 14 % of the water in
   the dam break, its particles crowding into the interface cells),
   :math:`p^{n+1} = p^n + \delta p` (``flow.pressure_step = "total"``:
   :math:`p^{n+1} = \delta p`, the explicit source being :math:`g` alone) — the
   :class:`~pfem2x.physics.flow.projection.PressureProjection`, shared with the
   Eulerian frame.
4. **Increment** back to the particles: :math:`u_p \mathrel{+}= (u^{n+1} -
   \hat u)(x_p)`, never overwritten; with ``flow.pic_fraction`` = α > 0 the
   result is blended, :math:`u_p \leftarrow (1-\alpha)u_p + \alpha u^{n+1}(x_p)`
   (α = 0: pure FLIP, the paper's scheme; small α damps sub-cell noise at
   the price of numerical viscosity). ``flow.affine = true`` (APIC): the
   particles also keep :math:`C_p = \alpha_p\nabla u^{n+1}(x_p)` (the share
   they took from the mesh; 0 for FLIP particles) and step 2 averages
   :math:`u_p + C_p(x_i - x_p)` instead of :math:`u_p`
   (:meth:`LagrangianFlow._project_affine`): the mesh velocity's gradient is
   not lost with the PIC share, and a linear velocity is projected exactly.
   Dam break (100 × 50, Courant 5, air α = 1): water volume change 0.43 /
   0.59 % (seeds 1 / 2) instead of 0.88 / 0.91 %, front unchanged.
5. **Population**: cells outside ``method.min_particles_per_cell`` /
   ``max_particles_per_cell`` get / lose particles; new ones take ``u`` (or only
   ``phase``, ``dist``: ``flow.new_particle_velocity``) from a fit of their
   neighbours (the phase then rounded to 0/1: it stays sharp).

Two phases with gravity: :math:`\rho g` is replaced everywhere (source :math:`a`,
pressure step) by the balanced force of :mod:`pfem2x.physics.flow.balanced`,
built on the zero iso-line of the particles' signed distance ``dist``
(set from the region at the start, carried like ``phase``, projected to P1
with the linear-exact fit, so a flat layer gives a flat iso-line; shifted
to keep the heavy volume, step 2), the same iso-line as the density's: a flat
interface inside cells stays at rest to solver tolerance. With
``flow.pressure_step = "total"`` the force is part of the pressure step and
the particles get no explicit source.

``flow.extra_pass = true`` repeats steps 1–4 once from the start-of-step
particles with :math:`\theta = 1/2` in eq. 2.10 — step 6 of the paper: the
particles follow the velocity and source blended linearly in time from the start
of the step to the first pass's end (``flow.pass_splits``), the first pass being
:math:`\theta = 0` or extrapolated from the last step (``flow.predictor``), the
second pass's viscous predictor second order in :math:`\Delta t`
(``flow.viscous_step``): :mod:`pfem2x.physics.flow.passes`.

Operators per step (``fem.COUNTERS``): 1 matrix assembly (pressure; +1 for the viscous
matrix when the phases' viscosities differ), 4 vector assemblies (lumped mass, pressure
right-hand side, correction, source :math:`a`), 2 solves (viscous predictor, pressure; 1
without viscosity); twice that with ``flow.extra_pass`` (+1 solve: the second pass's
two-stage viscous predictor); once per step +2 vectors (right-hand side, source :math:`a`;
+1, the vorticity, with one viscous phase) and +1 solve for the consistent pressure (twice
that with ``flow.pass_pressure = "consistent"``); +1 vector (the heavy phase's source) with
``flow.light_source = "gravity"``.
Large density ratios (dam break, 1000) run with the frame's defaults for two phases:
``flow.pass_pressure = "auto"`` takes the second pass's end source from the consistent
pressure from a density ratio of 10 on (:math:`p^n + \delta p^{(1)}` throws the air around
and diverges from ratio 100 on), ``flow.divergence_rtol = "auto"`` the discrete projection
(the water particles' volume); docs/RESULTS.md, "Dam break". The total-pressure set
(``flow.pressure_step = "total"``, ``flow.pic_fraction_light = 1``, ``flow.affine`` and
``flow.mass_weighted``) is first order in :math:`\Delta t`, an alternative only.

Scene keys this frame reads (besides the problem's: ``flow.gravity``, the
sides, ``initial_velocity``, ``velocity_scale``, ``time_factor``,
``max_speed``, ``[phases]``):

==================================  =====================================================
key                                 effect in this frame
==================================  =====================================================
``method.particles_per_cell``       particles seeded per cell
``method.min_particles_per_cell``   step 5: cells with fewer get particles (0: off)
``method.max_particles_per_cell``   step 5: cells with more lose particles (0: off)
``method.seed``                     seeding and population control
``method.projection``               step 2 (``auto`` = ``average``)
``method.substep_courant``          step 1: cells per X-IVAS sub-step
``method.substep_gradient``         step 1: turning per sub-step
``method.preconditioner``           pressure solve (cg); the viscous solve is cg/Jacobi
``flow.pressure_step``              ``increment`` (source :math:`g - \nabla p^n/\rho`) or ``total``
``flow.explicit_pressure``          step 1: ``consistent`` (solved from :math:`u^n`) or ``lagged``
``flow.correction``                 ``velocity`` or ``momentum`` (step 3)
``flow.extra_pass``                 step 6 of the paper (second pass, :math:`\theta = 1/2`)
``flow.pass_splits``                the second pass's move: one, linear in time, or m parts
``flow.predictor``                  the first pass: ``extrapolated`` or ``euler``
``flow.viscous_step``               the second pass's viscous predictor: ``sdirk2`` or ``euler``
``flow.pass_pressure``              the second pass's end source (``increment``, ``consistent``)
``flow.pic_fraction``               step 4 blend towards the mesh velocity (0: FLIP)
``flow.pic_fraction_light``         the same for the light phase (two phases)
``flow.light_source``               ``full`` or ``gravity`` (see :meth:`LagrangianFlow._kick`)
``flow.mass_weighted``              mass-weighted velocity projection (two phases)
``flow.density``                    ``level_set`` (cut cells of ``dist``) or ``particles``
``flow.affine``                     step 2/4: APIC (particles carry the PIC share of grad u)
``flow.rtol``                       tolerance of every linear solve
``flow.surface_tension``            capillary force on ``dist`` (:mod:`.capillary`)
``flow.capillary_increment``        the force's increment through the momentum operator
``flow.capillary_damping``          implicit term on the whole or the normal velocity
``flow.particle_redistance``        ``dist`` near the interface to the fitted circles
==================================  =====================================================

Ignored here: ``method.theta``, ``method.supg``, ``flow.interface_width``,
``flow.reinit_every``, ``flow.quadrature_degree`` (the forms are integrated exactly: DG0
coefficients, P1 fields), ``flow.volume_correction`` (with gravity the level set ``dist``
always keeps the phase volume, step 2).

Open sides (one phase, :mod:`.open_sides`): particles that leave through an ``outflow``
side are deleted in the move; after each move the cells within one step's inflow travel
of an ``inflow`` side are topped up to ``method.particles_per_cell``, and the particles
there whose path of the step came in through the side take ``flow.inflow_velocity``
where it crossed plus the step's source; the viscous predictor lifts the inflow values
through its operator. Limitations: two phases with box sides ``slip`` / ``noslip``
only; 2D.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem
from pfem2x import particles as P
from pfem2x.compat import MPI, PETSc
from pfem2x.mesh import Domain
from pfem2x.physics.flow.balanced import JumpForce
from pfem2x.physics.flow.loads import CellLoads
from pfem2x.physics.flow.open_sides import OpenSides
from pfem2x.physics.flow.passes import SDIRK_GAMMA, TwoPasses
from pfem2x.physics.flow.pfem2_capillary import ParticleCapillary
from pfem2x.physics.flow.problem import FlowSolver
from pfem2x.physics.flow.projection import PressureProjection
from pfem2x.physics.flow.transfers import ParticleTransfers
from pfem2x.physics.flow.vorticity import RotationalViscousTerm
from pfem2x.scene import Scene

__all__ = ["LagrangianFlow"]


class LagrangianFlow(TwoPasses, OpenSides, ParticleCapillary, ParticleTransfers, FlowSolver):
    """PFEM-2 fractional-step NS with particle velocity and sharp particle phase.

    See the module docstring for the step. Diagnostics are those of
    :class:`~pfem2x.physics.flow.problem.FlowSolver` with these choices: phase volumes from the
    cells' phase-1 fractions (what the density uses: the cut cells of the level set ``dist``
    with the balanced gravity, else the particles' phase); ``level_shift`` the last
    volume-keeping shift of ``dist`` (:meth:`_conserve_volume`); ``tip_falling`` /
    ``tip_rising`` from the ``phase = 1/2`` iso-line of the P1-projected
    phase (like interFoam's ``alpha = 0.5``); ``tip_*_particles`` the extreme
    particle of each phase; ``particles`` the global count.
    """

    name = "flow-lagrangian"
    checkpoint_state = ("rho", "mu", "frac", "u_hat", "force", "force_heavy", "du", "_u_old",
                        "_mom_nodes", "step_count", "dist", "_a_old")  # fmt: skip

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        self._update_inflow(0.0)  # (the inflow sides' values, before u gets its conditions)
        self._require_finite_inflow()
        pr = self.problem
        fl = scene.flow
        mesh = domain.mesh
        self.pic_fraction = float(fl.pic_fraction)
        self.pic_fraction_light = float(fl.pic_fraction_light) if pr.two_phase else 0.0
        self.mass_weighted = bool(fl.mass_weighted) and pr.two_phase
        #: flow.affine: particles carry the mesh velocity gradient C_p (APIC transfer)
        self.affine = bool(fl.affine)
        # flow.pressure_step = "total": every particle gets g only (the pressure step
        # then supplies the whole pressure acceleration each step)
        self.gravity_only = not pr.incremental
        self.light_gravity_only = (
            pr.two_phase and fl.light_source == "gravity" and not self.gravity_only
        )
        self.extra_pass = bool(fl.extra_pass)
        #: the second pass's move linear in time (0) or in m parts (flow.pass_splits, .passes)
        self.pass_splits = int(fl.pass_splits)
        #: the second pass's viscous predictor by the two-stage SDIRK (flow.viscous_step)
        self.viscous_sdirk = fl.viscous_step == "sdirk2"
        #: the explicit source's pressure solved from u^n each step (flow.explicit_pressure)
        self.consistent_pressure = not self.gravity_only and fl.explicit_pressure == "consistent"
        #: the second pass's end source from the pressure of u^(1) (flow.pass_pressure)
        pp = self.problem.pass_pressure
        self.consistent_end_source = self.consistent_pressure and pp == "consistent"
        #: the source integrated along the path (False: its end points; for measurements)
        self.path_source = True
        #: mean sub-steps per particle of the last move's source integral
        self.path_substeps = 1
        #: two phases with gravity: the level set ``dist`` is shifted to keep the heavy
        #: phase's volume (:meth:`_conserve_volume`; False: not, kept for measurements)
        self.conserve_volume = True
        #: flow.density = "level_set": the density from the cut cells of the shifted dist
        self.level_set_density = fl.density == "level_set"
        self.level_shift = 0.0  # the last shift of ``dist``
        self.dt_c = compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))

        # cell-wise density / viscosity from the particles
        self.W0 = compat.function_space(mesh, 0, family="DG")
        self._cell_dofs = compat.dofmap_array(self.W0)[: self.n_owned, 0]
        self.rho = compat.dolfinx.fem.Function(self.W0, name="rho")
        self.mu = compat.dolfinx.fem.Function(self.W0, name="mu")
        self.frac = np.zeros(self.n_owned)  # phase-1 fraction of each owned cell
        self.u_hat = compat.dolfinx.fem.Function(self.V)
        self.force = compat.dolfinx.fem.Function(self.V)  # a = g - grad(p)/rho (P1)
        self.du = compat.dolfinx.fem.Function(self.V)
        self._u_old = compat.dolfinx.fem.Function(self.V)  # u^n for the extra pass
        #: a^n of the last step (flow.predictor = "extrapolated", :mod:`.passes`)
        self._a_old = None
        if self.extra_pass and fl.predictor == "extrapolated":
            self._a_old = compat.dolfinx.fem.Function(self.V)
        self.force_heavy: Any = None  # flow.light_source = "gravity": the heavy phase's a
        #: two phases with gravity: the balanced body force and the level set it is
        #: built from (the P1 projection of the particles' signed distance)
        self.jump: JumpForce | None = None
        self.dist: Any = None
        if pr.two_phase and np.any(pr.gravity):
            self.jump = JumpForce(
                self.Q, self.interface, pr.phases[0][1], pr.phases[1][1],
                pr.gravity[: self.gdim], 2.0 * self.H,
            )  # fmt: skip
            self.dist = compat.dolfinx.fem.Function(self.Q, name="dist")
        self._init_capillary()
        self._seed_particles()
        self._update_phase_fields()
        self._forms()
        compat.set_bc(compat.petsc_vec(self.u), self._bcs_u)
        self.u.x.scatter_forward()
        #: the pressure operator and the lumped mass are not those of the current
        #: density (see :meth:`_consistent_pressure`)
        self._operator_stale = True
        if np.any(pr.gravity) or self.capillary is not None:
            self.projection.initial_pressure(self.p)
            self._operator_stale = False
        self.projection.assemble_mass()
        self._update_force()
        self.volume0 = self.phase_volumes()

    def _seed_particles(self) -> None:
        """The cloud: ``u`` from the mesh velocity, ``phase`` from the region (two phases)."""
        pr = self.problem
        meth = self.scene.method
        fields: dict[str, Any] = {"u": (self.gdim,)}
        if pr.two_phase:
            fields["phase"] = ()
        if self.mass_weighted:
            fields["_mom"] = (self.gdim + 1,)  # work field: (rho u, rho) of each particle
        if self.affine:
            fields["grad_u"] = (self.gdim**2,)  # C_p = grad u at the particle (row-major)
            # work field: (u - C x, C) of each particle (times rho, and rho, mass-weighted)
            fields["_aff"] = (self.gdim + self.gdim**2 + int(self.mass_weighted),)
        self.cloud_ = P.Cloud(
            self.domain, fields, outflow=self._sides("outflow"), inflow=self._sides("inflow")
        )
        # nodal (sum w rho u, sum w rho) / sum w of the mass-weighted projection
        self._mom_nodes = np.zeros((len(self.coords), self.gdim + 1))
        self._mom_nodes[:, -1] = 1.0
        P.seed_cells(self.cloud_, meth.particles_per_cell, seed=meth.seed)
        P.interpolate(self.cloud_, "u", self.u)
        if self.affine:
            self._set_affine()
        if pr.two_phase:
            region = pr.phases[0][3]
            x = self.cloud_.x
            x3 = np.zeros((len(x), 3))
            x3[:, : self.gdim] = x
            self.cloud_.field("phase")[:] = np.asarray(region(x3, 0.0), dtype=bool)
            if self.dist is not None:
                # the signed distance to the region's boundary (> 0 inside), P1 at the start
                self.dist.x.array[:] = self.interface.signed_distance(region)
                P.interpolate(self.cloud_, "dist", self.dist)
                self._seed_capillary_dist(region)
        self.last_population = P.PopulationStats()
        self.step_count = 0

    def _forms(self) -> None:
        """Pressure projection, viscous stiffness and the particles' source ``a``."""
        pr = self.problem
        mesh = self.domain.mesh
        dx = ufl.dx(domain=mesh)
        grav = bool(np.any(pr.gravity))  # without gravity no form has a body force
        g = compat.dolfinx.fem.Constant(mesh, np.asarray(pr.gravity, dtype=PETSc.ScalarType))
        # gravity: rho g with one phase, the balanced force with two
        f_body = (
            (self.jump.force(self.rho, g) if self.jump is not None else self.rho * g)
            if grav
            else None
        )
        if self.capillary is not None:  # surface tension: the balanced capillary force
            fc = self.capillary.force(self._phase_weight())
            f_body = fc if f_body is None else f_body + fc
            grav = True  # (the forms below take f_body as the body force)
        self._use_projection(
            PressureProjection(
                self.V, self.Q, self.gdim, self.rho, f_body, dx,
                self.dt_c, self._bcs_u, self._bcs_p, pr.correction, pr.incremental,
                self.scene.method.preconditioner, pr.rtol, self.timer,
                force_in_projection=(self.jump is not None or self.capillary is not None)
                and not pr.incremental, divergence_rtol=pr.divergence_rtol,
                divergence_preconditioner=pr.divergence_preconditioner,
                cell_dofs=self._cell_dofs,
            )
        )  # fmt: skip
        v, w = ufl.TrialFunction(self.V), ufl.TestFunction(self.V)
        mus = {m for (_, _, m, _) in pr.phases}
        self.viscous = max(mus) > 0.0
        self.mu_varies = len(mus) > 1
        a_K = pr.viscous_form(self.mu, v, w) * dx
        if self.capillary is not None:  # the semi-implicit Laplace-Beltrami term
            a_K = a_K + self.capillary.implicit_form(v, w, self.dt_c) * dx
        self.a_K = compat.form(a_K)
        self.K: Any = None
        self.A_m: Any = None
        self.m_solver: fem.LinearSolver | None = None
        if not self.gravity_only:  # total pressure: the particles get g only, no source form
            a_rho = f_body - ufl.grad(self.p) if grav else -ufl.grad(self.p)
            self.L_f = compat.form(ufl.dot(a_rho, w) * dx)
            self.b_f = compat.create_vector(self.L_f)
        if self.light_gravity_only:
            # heavy particles: a_heavy = g - M^-1 int grad(p).w / rho_heavy (lumped M)
            self.force_heavy = compat.dolfinx.fem.Function(self.V)
            a_h = -ufl.grad(self.p) / pr.phases[0][1]
            if grav:  # (balanced force: the heavy phase's b / rho_heavy is g in its bulk)
                a_h = a_h + (f_body / pr.phases[0][1] if self.jump is not None else g)
            self.L_fh = compat.form(ufl.dot(a_h, w) * dx)
            self.b_fh = compat.create_vector(self.L_fh)
        self.L_pc, self.vort = None, None  # (and nu lap(u) = -nu curl(omega_h), one phase)
        if self.consistent_pressure:  # grad(u):grad(u)^T r + (f / rho).grad(r)
            r = ufl.TestFunction(self.Q)
            gu = ufl.grad(self.u)
            L_pc = ufl.inner(gu, ufl.transpose(gu)) * r * dx
            if grav:
                L_pc = L_pc + (1.0 / self.rho) * ufl.dot(f_body, ufl.grad(r)) * dx
            if self.viscous and not pr.two_phase:
                self.vort = RotationalViscousTerm(self.u, self.mu / self.rho, self.domain.table)
                L_pc = L_pc + self.vort.term(r) * dx
            self.L_pc = compat.form(L_pc)
        #: the source load and the consistent pressure's right-hand side cell by cell
        #: (DG0 density, no surface tension: :mod:`.loads`), or None: by their forms
        self.loads: CellLoads | None = None
        if self.capillary is None and self.projection.cell_density is not None:
            self.loads = CellLoads(self.V, self.Q, np.asarray(pr.gravity) * grav, self.jump)
        #: that right-hand side by :attr:`loads` (no viscous term, no pressure condition)
        self._pc_cellwise = self.loads is not None and self.vort is None and not self._bcs_p
        self.b_m = compat.create_vector(self.projection.L_mass)
        self._bc_rows: np.ndarray | None = None  # (owned rows set by the velocity's conditions)
        self._diag = compat.create_vector(self.projection.L_mass)

    # -- phase / density (the fractions and fields: :mod:`.transfers`) ------------
    def cell_density(self) -> np.ndarray:
        """Density of each owned cell: the DG0 density of the cell's phase-1 fraction."""
        return self.rho.x.array[self._cell_dofs]

    def phase_volumes(self) -> dict[str, float]:
        """Phase volumes from the cells' phase-1 fractions (what the density uses).

        With the balanced gravity the cut-cell fractions of the P1 ``dist`` (kept at
        the initial volume by :meth:`_conserve_volume`), else the fractions of
        phase-1 particles.
        """
        names = [p[0] for p in self.problem.phases]
        total = float(self.comm.allreduce(self.cell_vol.sum(), op=MPI.SUM))
        if not self.problem.two_phase:
            return {names[0]: total}
        v1 = float(self.comm.allreduce(float(np.dot(self.frac, self.cell_vol)), op=MPI.SUM))
        return {names[0]: v1, names[1]: total - v1}

    def _update_force(self) -> None:
        """``a = M_rho^-1 int (rho g - grad p).w`` at the nodes (needs ``b_mass``)."""
        if self.gravity_only:
            return
        if self.loads is not None:
            self.loads.force(self.cell_density(), self.p, self.b_f)
        else:
            fem.assemble_vector(self.L_f, self.b_f)
        n = len(self.b_f.array_r)
        self.force.x.array[:n] = self.b_f.array_r / self.projection.b_mass.array_r
        self.force.x.scatter_forward()
        if self.light_gravity_only:
            fem.assemble_vector(self.L_fh, self.b_fh)
            self.force_heavy.x.array[:n] = self.b_fh.array_r / self.projection.b_lumped.array_r
            self.force_heavy.x.scatter_forward()

    # -- the step -----------------------------------------------------------------
    def _move(self, dt: float, theta: float) -> None:
        r"""Step 1: X-IVAS move along ``u^n`` (+ ``theta``: ``u^{n+1}``), the source on the path.

        Eq. 2.9: the source :math:`a` (a P1 vector field, see :meth:`_kick`) is
        integrated along each particle's path inside the move itself
        (:func:`pfem2x.particles.advect` with a vector source): the trapezoid rule
        on every sub-step of the move, each crossing at most ``method.substep_courant``
        cells (one sample per cell crossed: :math:`a` is constant enough per cell)
        and turning at most ``method.substep_gradient``; then
        :math:`u_p \mathrel{+}= \int a\,dt`. With ``flow.light_source = "gravity"``
        the light phase's particles get :math:`g\,\Delta t` instead. With
        ``flow.pressure_step = "total"`` (the source is :math:`g` or nothing) and
        without :attr:`path_source`: the trapezoid of the path's two end points.
        """
        c = self.cloud_
        meth = self.scene.method
        vel = self._u_old if theta > 0.0 else self.u
        kw: dict[str, Any] = {
            "courant": meth.substep_courant * self._substep_scale,
            "gradient_courant": meth.substep_gradient * self._substep_scale,
        }
        if theta > 0.0:
            kw.update(velocity_next=self.u, theta=theta)
        if self.gravity_only or not self.path_source:
            self.path_substeps = 1
            self._kick(0.5 * dt)
            P.advect(c, vel, dt, **kw)
            self._kick(0.5 * dt)  # storage may have been reordered / migrated in between
            return
        if theta > 0.0:
            # the limit of X-IVAS sub-steps h -> 0: the streamline of the blended velocity
            # (the Newton stage of one X-IVAS step over dt would leave the source's path)
            kw = {k: kw[k] for k in ("courant", "gradient_courant")}
            vel = (1.0 - theta) * self._u_old.x.array + theta * self.u.x.array
            vel = vel.reshape(-1, self.gdim)
        if not self.light_gravity_only:
            stats = P.advect(c, vel, dt, source=self.force, source_field="u", **kw)
        else:
            stats = P.advect(c, vel, dt, source=self.force_heavy, source_field="_kick", **kw)
            f = c.field("_kick")
            f[c.field("phase") < 0.5] = dt * np.asarray(self.problem.gravity)
            c.field("u")[:] += f
            c.remove_field("_kick")
        self._count_substeps(stats)

    def _kick(self, h: float) -> None:
        r"""``u_p += h a(x_p)``, the explicit source of step 1.

        ``flow.light_source = "full"``: :math:`a = M_\rho^{-1}\int(\rho g - \nabla p^n)\cdot w`
        for every particle. ``"gravity"`` (large density ratios): particles of
        the light phase get :math:`g` only, those of the heavy phase
        :math:`a_h = g - M^{-1}\int\nabla p^n\cdot w/\rho_{heavy}`. The light
        phase's pressure acceleration is of order :math:`g\rho_{heavy}/\rho_{light}`
        in the cells next to the interface, where the P1 pressure cannot follow
        the kink of the hydrostatic gradient; as an explicit source it throws
        the air (and drops flying in it, with the mixture's nodal mass) around
        (dam break, ratio 1000). The pressure step then supplies the light
        phase's whole pressure acceleration each step, and heavy drops in the
        light phase fall freely. ``flow.pressure_step = "total"``: every particle
        gets :math:`g` only; the pressure step solves the whole pressure.
        Measured on the dam break (ratio 1000): with the heavy phase's explicit
        :math:`-\nabla p^n/\rho_{heavy}` the kick added kinetic energy beyond
        the potential energy released (+24 % at Courant 2 once the phase volume
        is conserved), because in cut cells the P1 pressure under-supports the
        water; with gravity only the kinetic energy stays below it.
        """
        c = self.cloud_
        if self.gravity_only:
            # (balanced force: the pressure step has all of b - grad p, no particle source)
            if np.any(self.problem.gravity) and self.jump is None:
                up = c.field("u")
                up += h * self.problem.gravity
            return
        if self.light_gravity_only:
            f = P.evaluate(c, self.force_heavy)
            f[c.field("phase") < 0.5] = self.problem.gravity
        else:
            f = P.evaluate(c, self.force)
        up = c.field("u")
        up += h * f

    def _mesh_step(self, dt: float) -> None:
        """Step 3: viscous predictor, pressure increment, correction; new source ``a``."""
        proj = self.projection
        with self.timer("assembly"):
            proj.assemble_mass()
            if self.viscous:
                self._viscous_operator(SDIRK_GAMMA * dt if self._viscous_l_stable else dt)
        if self.viscous and self._viscous_l_stable:
            self._viscous_sdirk2(dt)
        elif self.viscous:
            with self.timer("solve"):
                self.u_star.x.array[:] = self.u_hat.x.array  # the start: no viscous change
                x, rtol = compat.petsc_vec(self.u_star), proj.pass_rtol  # (first pass: its own)
                proj.iterations["momentum"] = self.m_solver.solve(self.b_m, x, True, rtol)
                self.u_star.x.scatter_forward()
        else:
            with self.timer("assembly"):
                self.u_star.x.array[:] = self.u_hat.x.array
                compat.set_bc(compat.petsc_vec(self.u_star), self._bcs_u)
                self.u_star.x.scatter_forward()
        with self.timer("assembly"):
            proj.assemble_operator()
            self._operator_stale = False
        proj.solve_increment()
        with self.timer("assembly"):
            proj.correct(self.u, self.p, dt, mass_ready=True)
            self._update_force()

    def _viscous_operator(self, dt: float) -> None:
        """``M_rho/dt + K_mu`` and its right-hand side ``M_rho u_hat/dt`` (needs ``b_mass``)."""
        b_mass = self.projection.b_mass
        n = len(b_mass.array_r)
        if self.K is None or self.mu_varies or self.capillary is not None:
            self.K = fem.assemble_matrix(self.a_K, self._bcs_u, self.K)
        if self.A_m is None:
            self.A_m = self.K.duplicate(copy=True)
        else:
            self.K.copy(self.A_m, PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
        self._diag.array[:] = b_mass.array_r / dt
        if self._inflow is not None:  # rows of the non-zero Dirichlet values: identity
            if self._bc_rows is None:
                self._bc_rows = compat.dirichlet_rows(self._diag, self._bcs_u)
            self._diag.array[self._bc_rows] = 0.0
        self.A_m.setDiagonal(self._diag, addv=PETSc.InsertMode.ADD_VALUES)
        self.b_m.array[:] = self._diag.array_r * self.u_hat.x.array[:n]
        self._set_viscous_bc()
        if self.m_solver is None:
            self.m_solver = fem.LinearSolver(self.A_m, "cg", "jacobi", rtol=self.problem.rtol)
        else:
            self.m_solver.set_operator(self.A_m)

    def _pass(self, dt: float, theta: float, blend: tuple | None = None) -> None:
        """Steps 1–4 of one pass; ``blend = (a0, a1, m)``: the move of :meth:`_blended_move`."""
        with self.timer("particles"):
            if blend is None:
                self._move(dt, theta)
            else:
                self._blended_move(dt, *blend)
            self._seed_inflow()
            self._update_phase_fields(velocity=True)
        self._mesh_step(dt)
        if self.capillary is not None and self.viscous and self.scene.flow.capillary_increment:
            self._capillary_increment(dt)
        with self.timer("particles"):
            self._increment_particles()

    def _consistent_pressure(self) -> None:
        r"""``p`` from the velocity ``u^n`` and the body force, and the source ``a`` from it.

        The pressure Poisson equation of a divergence-free velocity,
        :math:`\nabla\cdot(\rho^{-1}\nabla p) = \nabla\cdot(\rho^{-1} f + \nu\Delta u) -
        \nabla u : (\nabla u)^T` (ν Δu in the rotational form of :mod:`.vorticity`,
        one viscous phase only; natural conditions: on straight walls
        :math:`n\cdot(u\cdot\nabla u) = 0`), with the operator of the last
        pressure step (re-assembled after a restart). At rest: the hydrostatic start.
        """
        proj = self.projection
        if self._operator_stale:
            with self.timer("assembly"):
                proj.assemble_operator()
                proj.assemble_mass()
            self._operator_stale = False
        if self.vort is not None:
            self.vort.update()
        if self._pc_cellwise:
            with self.timer("assembly"):
                self.loads.pressure(self.cell_density(), self.u, proj.b_p)  # type: ignore[union-attr]
            proj.solve_assembled(self.p)
        else:
            proj.solve(self.L_pc, self.p)
        with self.timer("assembly"):
            self._update_force()

    def restore_checkpoint(self, *args: Any, **kwargs: Any) -> None:
        """As :meth:`Solver.restore_checkpoint`; then the pressure operator, mass and jump force."""
        super().restore_checkpoint(*args, **kwargs)
        self._operator_stale = True
        if self.jump is not None:  # the balanced force of the restored level set
            self.jump.update(self.dist.x.array)
        if self.capillary is not None:
            self.capillary.update(self.dist.x.array, self.cell_vol)

    def step(self, t: float, dt: float) -> None:
        self.dt_c.value = dt
        self._t_next = t + dt
        self._dt_step = dt
        self._update_inflow(t + dt)
        if self.consistent_pressure:
            self._consistent_pressure()
        c = self.cloud_
        if self.extra_pass:
            self._two_passes(dt)  # (reads the last step's dt_last)
        else:
            self._pass(dt, 0.0)
        self.dt_last = dt
        with self.timer("particles"):
            self._rebalance()
        self.step_count += 1
        self.steps_done += 1
        self.require_finite("particle velocity", c.field("u"))
        self._check()

    # -- output / diagnostics -----------------------------------------------------
    def cloud(self) -> Any:
        return self.cloud_

    def snapshot_field(self) -> tuple[str, Any]:
        """The P1-projected phase (two phases) or the speed field's first component."""
        if self.phase is not None:
            return "phase", self.phase
        return "u", self.u

    def diagnostics(self, t: float) -> dict[str, float]:
        d = super().diagnostics(t)
        c = self.cloud_
        d["particles"] = float(c.global_count())
        if self.problem.two_phase:
            ph = c.field("phase") > 0.5
            y = c.x[:, 1]
            lo = y[ph].min() if ph.any() else np.inf
            hi = y[~ph].max() if (~ph).any() else -np.inf
            d["tip_falling_particles"] = float(self.comm.allreduce(lo, op=MPI.MIN))
            d["tip_rising_particles"] = float(self.comm.allreduce(hi, op=MPI.MAX))
        if self.jump is not None and self.level_set_density:
            d["level_shift"] = self.level_shift
            # the particles' own phase volume (not the density's): the transport's drift
            v = float(np.dot(self._particle_fraction(), self.cell_vol))
            d[f"volume_particles_{self.problem.phases[0][0]}"] = float(
                self.comm.allreduce(v, op=MPI.SUM)
            )
        return d

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        """As :meth:`FlowSolver.metrics`; with the balanced gravity also the particles' volume.

        ``volume_particles_<heavy>`` (first and last) and
        ``volume_change_max_particles_<heavy>``: the phase volume of the particles'
        cell fractions, which the shifted level set does not follow
        (:meth:`_conserve_volume`), i.e. what the transport alone keeps.
        """
        out = super().metrics(history)
        key = f"volume_particles_{self.problem.phases[0][0]}"
        if history and key in history[0]:
            v = np.array([h[key] for h in history])
            out[key] = [float(v[0]), float(v[-1])]
            out[key.replace("volume_", "volume_change_max_", 1)] = float(
                np.max(np.abs(v / v[0] - 1.0))
            )
        return out
