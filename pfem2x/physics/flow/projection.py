r"""The pressure step of the fractional-step flow frames, as one object.

Given the predicted velocity :math:`u^*` (:attr:`PressureProjection.u_star`):

- pressure increment :math:`\int\rho^{-1}\nabla\delta p\cdot\nabla r =
  -\Delta t^{-1}\int(\nabla\cdot u^*)\,r` (constant null space removed without
  a pressure condition, else :math:`\delta p = 0` on outflow sides);
- correction :math:`u = u^* - \Delta t\,M^{-1}\int\rho^{-1}\nabla\delta p\cdot w`
  (``flow.correction = "velocity"``, :math:`M` the lumped mass) or
  :math:`u = u^* - \Delta t\,M_\rho^{-1}\int\nabla\delta p\cdot w`
  (``"momentum"``, :math:`M_\rho` the :math:`\rho`-weighted lumped mass);
  :math:`p \mathrel{+}= \delta p` (``flow.pressure_step = "increment"``) or
  :math:`p = \delta p` (``"total"``);
- hydrostatic start :math:`\nabla\cdot(\rho^{-1}(\nabla p - f)) = 0` with the body
  force :math:`f` (:math:`\rho g`, or the balanced force of two phases,
  :mod:`pfem2x.physics.flow.balanced`);
- ``force_in_projection`` (the balanced force with ``flow.pressure_step =
  "total"``): the body force enters the pressure step in the same form as the
  pressure gradient, :math:`\int\rho^{-1}(\nabla p - f)\cdot\nabla r =
  -\Delta t^{-1}\int(\nabla\cdot u^*)\,r` and
  :math:`u = u^* - \Delta t\,M^{-1}\int\rho^{-1}(\nabla p - f)\cdot w`
  (the predictor has neither), so a force that is a discrete gradient is
  balanced by the pressure exactly.

The increment above is the *approximate* projection: its operator is the
Laplacian, not the correction's own :math:`S = -D\,P M^{-1} G` (:math:`D` the weak
divergence :math:`\int(\nabla\cdot v)\,r`, :math:`G` the correction's gradient
:math:`\int\rho^{-1}\nabla q\cdot w`, :math:`P` zeroing the rows the velocity's
conditions set), so the corrected velocity is weakly divergence-free only up to
:math:`(L + S)\,\delta p`, a residual that sits where :math:`\delta p` varies on the
mesh scale: at a density jump, where the particles then gather in the cut cells.
``flow.divergence_rtol`` > 0 (the *discrete* projection; the ``"velocity"``
correction, closed boxes) removes what is left: after the correction,
:math:`S q = -\Delta t^{-1} D u`, :math:`u \mathrel{-}= \Delta t\,P M^{-1} G q`,
:math:`p \mathrel{+}= q`, by GMRES from 0, right-preconditioned by the pressure solve's
own AMG (``flow.divergence_preconditioner = "pressure"``: its set-up for the same density,
no second one) or by the Laplacian's diagonal (``"jacobi"``: fewer and cheaper iterations,
but the particles keep their phase's volume less well: docs/BENCHMARKS.md, "The discrete
projection's preconditioner"), to that relative tolerance or at most 30 iterations (the P1 pair's
mesh-scale pressure modes are out of :math:`S`'s range: on a smooth flow the residual
stalls at a few per cent, and GMRES keeps its best iterate). A balanced state (no weak
divergence) is left as it is. One more matrix (:math:`G`, with the Laplacian) and one
GMRES solve per pressure step (docs/RESULTS.md, "Where the water particles' volume goes").

With a cellwise (DG0) density (the Lagrangian frame's, ``cell_dofs``) and a closed box,
the Laplacian, :math:`G` and the lumped mass :math:`M_\rho` are re-assembled from their
element tensors as sparse products (:mod:`pfem2x.cellwise`), the increment's right-hand
side is :math:`-\Delta t^{-1} D u^*` with :math:`D` assembled once, and with the
discrete projection the correction is :math:`u = u^* - \Delta t\,PM^{-1}G\,\delta p`
(its own matrix): the same operators to round-off, without a form assembly per pass.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import ufl

from pfem2x import cellwise, compat, fem
from pfem2x.cellwise import CellwiseForm
from pfem2x.compat import PETSc
from pfem2x.mesh import geometry_table

__all__ = ["PressureProjection"]


class PressureProjection:
    """Forms, operator, solve and correction of the pressure step.

    Parameters
    ----------
    V, Q
        The P1 velocity and pressure spaces.
    gdim
        Geometric dimension (components of the velocity).
    rho
        UFL density (smoothed level set, a DG0 function, a constant).
    f_body
        UFL body force per volume (:math:`\\rho g`) for the hydrostatic start;
        ``None`` without gravity (nothing assembled).
    dxq
        The cell measure.
    dt_c
        The time step as a DOLFINx ``Constant``.
    bcs_u, bcs_p
        Velocity and pressure Dirichlet conditions.
    correction
        ``"velocity"`` or ``"momentum"`` (``flow.correction``).
    incremental
        ``flow.pressure_step == "increment"``.
    preconditioner, rtol
        Of the pressure solve (``method.preconditioner``, ``flow.rtol``).
    timer
        ``timer("solve")`` times the pressure solves (the solver's :meth:`Solver.timer`).
    force_in_projection
        The body force ``f_body`` enters the pressure equation and the correction
        (with ``incremental = False``; see the module docstring).
    divergence_rtol
        > 0: the discrete projection to this tolerance (see the module docstring).
    divergence_preconditioner
        The discrete projection's GMRES preconditioner: ``"pressure"`` (the pressure
        solve's own) or ``"jacobi"`` (the diagonal of the pressure step's Laplacian).
    cell_dofs
        ``rho`` is a DG0 function and these are its owned cells' dofs: the
        operators that change with it (the Laplacian, the lumped mass, the discrete
        projection's gradient) are re-assembled as sparse products of their element
        tensors (:mod:`pfem2x.cellwise`; closed boxes), and the
        increment's right-hand side and the correction of the discrete projection
        are products with its matrices. ``None``: every form by DOLFINx.
    """

    def __init__(
        self,
        V: Any,
        Q: Any,
        gdim: int,
        rho: Any,
        f_body: Any,
        dxq: Any,
        dt_c: Any,
        bcs_u: list,
        bcs_p: list,
        correction: str,
        incremental: bool,
        preconditioner: str,
        rtol: float,
        timer: Callable[[str], AbstractContextManager[None]],
        force_in_projection: bool = False,
        divergence_rtol: float = 0.0,
        cell_dofs: np.ndarray | None = None,
        divergence_preconditioner: str = "pressure",
    ):
        self.bcs_u, self.bcs_p = bcs_u, bcs_p
        self.dt_c = dt_c
        #: > 0: the discrete projection to this tolerance (see the module docstring)
        self.divergence_rtol = float(divergence_rtol)
        #: the discrete projection's preconditioner ("pressure" or "jacobi")
        self.divergence_preconditioner = divergence_preconditioner
        if self.divergence_rtol > 0.0 and (bcs_p or correction != "velocity"):
            raise ValueError("the discrete projection needs a closed box and correction = velocity")
        self._discrete: _DiscreteProjection | None = None
        self.correction = correction
        self.incremental = incremental
        self.preconditioner, self.rtol = preconditioner, rtol
        self.timer = timer
        #: the predicted velocity u* and the pressure increment dp
        self.u_star = compat.dolfinx.fem.Function(V)
        self.dp = compat.dolfinx.fem.Function(Q)
        q, r = ufl.TrialFunction(Q), ufl.TestFunction(Q)
        w = ufl.TestFunction(V)
        self.a_p = compat.form((1.0 / rho) * ufl.dot(ufl.grad(q), ufl.grad(r)) * dxq)
        L_p = -(1.0 / dt_c) * ufl.div(self.u_star) * r * dxq
        #: the body force is part of the pressure step (balanced force, total pressure)
        self.force_in_projection = force_in_projection and f_body is not None
        if self.force_in_projection:
            L_p = L_p + (1.0 / rho) * ufl.dot(f_body, ufl.grad(r)) * dxq
        self.L_p = compat.form(L_p)
        #: the body force (UFL) in the forms; None without effects.gravity
        self.body_force = f_body
        L_p0 = None if f_body is None else (1.0 / rho) * ufl.dot(f_body, ufl.grad(r)) * dxq
        self.L_p0 = None if L_p0 is None else compat.form(L_p0)
        self.A_p: Any = None
        self.b_p = compat.create_vector(self.L_p)
        self.p_solver: fem.LinearSolver | None = None
        self.nullspace: Any = None
        ones = ufl.as_vector([1.0] * gdim)
        #: the rho-weighted lumped mass M_rho (form and vector)
        self.L_mass = compat.form(rho * ufl.dot(w, ones) * dxq)
        self.b_mass = compat.create_vector(self.L_mass)
        #: the plain lumped mass M (assembled once)
        self.b_lumped = compat.create_vector(self.L_mass)
        fem.assemble_vector(compat.form(ufl.dot(w, ones) * dxq), self.b_lumped)
        grad_dp = ufl.grad(self.dp)
        if self.force_in_projection:
            grad_dp = grad_dp - f_body
        if correction == "velocity":
            # u -= dt M^-1 int rho^-1 grad(dp).w: the pressure equation's own 1/rho
            self.L_c = compat.form(ufl.dot(grad_dp, w) / rho * dxq)
        else:
            self.L_c = compat.form(ufl.dot(grad_dp, w) * dxq)
        self.b_c = compat.create_vector(self.L_c)
        self._cellwise_forms(V, Q, gdim, dxq, rho, cell_dofs)
        if self.divergence_rtol > 0.0:
            self._discrete = _DiscreteProjection(V, Q, rho, dxq, self)
        #: iteration counts of the last solves, by equation
        self.iterations: dict[str, int] = {}
        #: the relative tolerances of the current pass's pressure solve and discrete
        #: projection where they differ from the scene's (PFEM-2's first pass), else None
        self.pass_rtol: float | None = None
        self.pass_divergence_rtol: float | None = None

    def _cellwise_forms(
        self, V: Any, Q: Any, gdim: int, dxq: Any, rho: Any, cell_dofs: np.ndarray | None
    ) -> None:
        """The operators re-assembled from :attr:`cell_density` (:mod:`pfem2x.cellwise`)."""
        #: the owned cells' density (``cell_dofs`` given), else None; a closure over
        #: ``rho`` alone, so that the frame and this object hold no reference cycle
        self.cell_density: Callable[[], np.ndarray] | None = None
        if cell_dofs is not None:
            cells = np.asarray(cell_dofs)
            self.cell_density = lambda: rho.x.array[cells]
        #: by name: "laplacian", "mass" and (discrete projection) "gradient"
        self._cellwise: dict[str, CellwiseForm] = {}
        #: the weak divergence D (int div(v) r), once: the increment's right-hand side
        #: -D u*/dt without an assembly (the density-free right-hand side, closed boxes)
        self.D: Any = None
        if self.cell_density is None or self.bcs_p:
            return
        table = geometry_table(V.mesh)  # (affine simplices: the table's own condition)
        qd, vd = compat.dofmap_array(Q), compat.dofmap_array(V)
        nq, nv = cellwise.local_size(Q), cellwise.local_size(V)
        self._cellwise["laplacian"] = CellwiseForm(
            *cellwise.p1_laplacian(table, qd), n_rows=nq, n_cols=nq
        )
        self._cellwise["mass"] = CellwiseForm(
            *cellwise.p1_lumped_mass(table, vd, gdim), None, n_rows=nv
        )
        if self.divergence_rtol > 0.0:
            self._cellwise["gradient"] = CellwiseForm(
                *cellwise.p1_gradient(table, vd, qd, gdim), n_rows=nv, n_cols=nq
            )
        if not self.force_in_projection:
            v, r = ufl.TrialFunction(V), ufl.TestFunction(Q)
            self.D = fem.assemble_matrix(compat.form(ufl.div(v) * r * dxq), [])

    def _inverse_density(self) -> np.ndarray:
        """``1 / rho`` of the owned cells (the cellwise operators' coefficient)."""
        return 1.0 / self.cell_density()  # type: ignore[misc]

    def assemble_operator(self) -> None:
        """(Re-)assemble the pressure operator (its density may have changed)."""
        if self.A_p is not None and "laplacian" in self._cellwise:
            self._cellwise["laplacian"].matrix(self._inverse_density(), self.A_p)
        else:
            self.A_p = fem.assemble_matrix(self.a_p, self.bcs_p, self.A_p)
            if "laplacian" in self._cellwise:  # the form's own matrix from now on
                self.A_p = self._cellwise["laplacian"].adopt(self.A_p)
        if not self.bcs_p:
            self.nullspace = compat.constant_nullspace(self.A_p)
        if self.p_solver is None:
            self.p_solver = fem.LinearSolver(self.A_p, "cg", self.preconditioner, rtol=self.rtol)
        else:
            self.p_solver.set_operator(self.A_p)
        if self._discrete is not None:
            self._discrete.assemble(self.A_p, self.nullspace, self.p_solver)

    def solve(self, L: Any, x: Any) -> None:
        """Solve the pressure operator against the right-hand side form ``L`` into ``x``."""
        fem.assemble_vector(L, self.b_p, self.a_p, self.bcs_p)
        self.solve_assembled(x)

    def solve_increment(self) -> None:
        """The pressure increment ``dp`` from the divergence of ``u_star``."""
        if self.D is None:
            self.solve(self.L_p, self.dp)
            return
        fem.COUNTERS["vector_assemblies"] += 1
        self.D.mult(compat.petsc_vec(self.u_star), self.b_p)
        self.b_p.scale(-1.0 / float(self.dt_c.value))
        self.solve_assembled(self.dp)

    def solve_assembled(self, x: Any) -> None:
        """Solve the pressure operator against :attr:`b_p` as it stands (assembled, its
        ghost rows added) into ``x`` (collective)."""
        if self.nullspace is not None:
            self.nullspace.remove(self.b_p)
        with self.timer("solve"):
            self.iterations["pressure"] = self.p_solver.solve(
                self.b_p, compat.petsc_vec(x), rtol=self.pass_rtol
            )
            x.x.scatter_forward()

    def initial_pressure(self, p: Any) -> None:
        """Hydrostatic start into ``p``: ``div(rho^-1 (grad p - rho g)) = 0``."""
        self.assemble_operator()
        self.solve(self.L_p0, p)

    def assemble_mass(self) -> None:
        """The rho-weighted lumped mass of the current density into :attr:`b_mass`."""
        if "mass" in self._cellwise:
            self._cellwise["mass"].vector(self.cell_density(), self.b_mass)
        else:
            fem.assemble_vector(self.L_mass, self.b_mass)

    def correct(self, u: Any, p: Any, dt: float, mass_ready: bool = False) -> None:
        """``u = u* - dt M^-1 grad(dp)`` with the velocity conditions; ``p += dp`` (or ``= dp``).

        ``mass_ready``: :attr:`b_mass` already holds the lumped mass of the
        current density (``"momentum"`` correction).
        """
        if self.D is not None and self._discrete is not None:
            # P M^-1 G dp: the discrete projection's own gradient (P zeroes the rows the
            # velocity's conditions set, as set_bc does after it)
            fem.COUNTERS["vector_assemblies"] += 1
            self._discrete.G.mult(compat.petsc_vec(self.dp), self._discrete.du)
            n = len(self._discrete.du.array_r)
            u.x.array[:n] = self.u_star.x.array[:n] - dt * self._discrete.du.array_r
            self._finish_correction(u, p, dt)
            return
        fem.assemble_vector(self.L_c, self.b_c)
        if self.correction == "velocity":
            mass = self.b_lumped
        else:
            if not mass_ready:
                self.assemble_mass()
            mass = self.b_mass
        n = len(self.b_c.array_r)
        u.x.array[:n] = self.u_star.x.array[:n] - dt * self.b_c.array_r / mass.array_r
        self._finish_correction(u, p, dt)

    def _finish_correction(self, u: Any, p: Any, dt: float) -> None:
        """The velocity's conditions, the pressure's update and the discrete projection."""
        compat.set_bc(compat.petsc_vec(u), self.bcs_u)
        u.x.scatter_forward()
        if self.incremental:
            p.x.array[:] += self.dp.x.array
        else:
            p.x.array[:] = self.dp.x.array
        if self._discrete is not None:
            with self.timer("solve"):
                self.iterations["discrete"] = self._discrete.polish(
                    u, p, dt, self.nullspace, self.pass_divergence_rtol
                )


class _DiscreteProjection:
    """The operators of the discrete projection (``flow.divergence_rtol`` > 0).

    :math:`D` (assembled once), :math:`PM^{-1}G` (with the density, re-assembled with
    the Laplacian; :math:`M^{-1}` the lumped mass's inverse with the velocity's
    condition rows zeroed), the Schur complement :math:`S = -DPM^{-1}G` applied as
    the two products (no matrix of it) and its GMRES solver, right-preconditioned by
    the pressure solver's own AMG (set up for the Laplacian of the same density by the
    pass's pressure solve: no second set-up) or by that Laplacian's diagonal
    (``proj.divergence_preconditioner``).
    """

    #: GMRES iterations at most (one restart cycle)
    MAX_IT = 30
    #: PETSc reasons of a stagnating GMRES (iteration limit, breakdown)
    STALLED = (-3, -5)

    def __init__(self, V: Any, Q: Any, rho: Any, dxq: Any, proj: PressureProjection):
        v, r = ufl.TrialFunction(V), ufl.TestFunction(Q)
        q, w = ufl.TrialFunction(Q), ufl.TestFunction(V)
        self.D = proj.D
        if self.D is None:
            self.D = fem.assemble_matrix(compat.form(ufl.div(v) * r * dxq), [])
        #: G from the cells' 1/rho (:mod:`pfem2x.cellwise`), or None: by its form
        self._gradient = proj._cellwise.get("gradient")
        density = proj.cell_density
        self._inverse_density = (lambda: 1.0 / density()) if density is not None else None
        self.a_G = compat.form(ufl.dot(ufl.grad(q), w) / rho * dxq)
        self.G: Any = None
        self.minv = compat.create_vector(proj.L_mass)
        fixed = compat.dirichlet_rows(self.minv, proj.bcs_u)
        self.minv.array[:] = np.where(fixed, 0.0, 1.0 / proj.b_lumped.array_r)
        self.rhs = compat.create_vector(proj.L_p)
        self.q = self.rhs.duplicate()
        self.du = compat.create_vector(proj.L_mass)
        self.rtol = proj.divergence_rtol
        if proj.divergence_preconditioner not in ("pressure", "jacobi"):
            raise ValueError(
                f"unknown divergence preconditioner {proj.divergence_preconditioner!r}"
            )
        self.jacobi = proj.divergence_preconditioner == "jacobi"
        self.ksp: Any = None
        self.S: Any = None

    def assemble(self, A_p: Any, nullspace: Any, p_solver: fem.LinearSolver) -> None:
        """:math:`PM^{-1}G` of the current density; the solver on first use (collective).

        ``A_p``, ``p_solver``: the pressure step's Laplacian of the same density and its
        solver, whose preconditioner (or ``A_p``'s diagonal) preconditions the GMRES.
        """
        if self.G is not None and self._gradient is not None:
            self._gradient.matrix(self._inverse_density(), self.G)
        else:
            self.G = fem.assemble_matrix(self.a_G, [], self.G)
            if self._gradient is not None:
                self.G = self._gradient.adopt(self.G)
        self.G.diagonalScale(L=self.minv)  # P M^-1 G
        if self.ksp is not None:
            if self.jacobi:  # (A_p's state tells PETSc to take its diagonal again)
                self.ksp.setOperators(self.S, A_p)
            return
        sizes = (self.rhs.getSizes(), self.rhs.getSizes())
        self.S = PETSc.Mat().createPython(sizes, _SchurProduct(self), comm=A_p.getComm())
        self.S.setUp()
        if nullspace is not None:
            self.S.setNullSpace(nullspace)
        ksp = PETSc.KSP().create(A_p.getComm())
        ksp.setOperators(self.S, A_p if self.jacobi else None)
        ksp.setType("gmres")
        ksp.setGMRESRestart(self.MAX_IT)
        ksp.setTolerances(rtol=self.rtol, atol=1e-50, max_it=self.MAX_IT)
        ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
        ksp.setPCSide(PETSc.PC.Side.RIGHT)
        pc = ksp.getPC()
        if self.jacobi:
            pc.setType(PETSc.PC.Type.JACOBI)  # the diagonal of A_p
        else:
            pc.setType(PETSc.PC.Type.PYTHON)
            pc.setPythonContext(_SharedPC(p_solver.ksp.getPC()))
        self.ksp = ksp

    def polish(self, u: Any, p: Any, dt: float, nullspace: Any, rtol: float | None = None) -> int:
        """``u -= dt P M^-1 G q``, ``p += q``: ``S q = -D u / dt`` (collective); GMRES iterations.

        ``u`` is the approximately projected velocity, ``q`` removes what is left of
        its weak divergence (nothing at rest: a balanced state stays balanced).
        ``rtol``: this solve's relative tolerance (``None``: :attr:`rtol`; 1 or more:
        nothing done).
        """
        if rtol is not None and rtol >= 1.0:
            return 0
        uv = compat.petsc_vec(u)
        self.D.mult(uv, self.rhs)
        self.rhs.scale(-1.0 / dt)
        if nullspace is not None:
            nullspace.remove(self.rhs)
        self.q.set(0.0)
        its = self.solve(self.rhs, self.q, rtol)
        self.G.mult(self.q, self.du)  # P M^-1 G q
        n = len(self.du.array_r)
        u.x.array[:n] -= dt * self.du.array_r
        u.x.scatter_forward()
        nq = len(self.q.array_r)
        p.x.array[:nq] += self.q.array_r
        p.x.scatter_forward()
        return its

    def solve(self, b: Any, x: Any, rtol: float | None = None) -> int:
        """GMRES on ``S`` from 0; its iterate is kept when it stops short of the tolerance.

        The weak divergence left by the P1 pair's pressure modes is out of ``S``'s
        range: GMRES then stagnates (a breakdown, or :attr:`MAX_IT` iterations)
        with the smallest residual it found, which is what the correction uses.
        Raises on a non-finite residual. ``rtol``: this solve's tolerance (``None``:
        :attr:`rtol`).
        """
        ksp = self.ksp
        fem.COUNTERS["solves"] += 1
        ksp.setTolerances(rtol=self.rtol if rtol is None else rtol)
        ksp.solve(b, x)
        reason = ksp.getConvergedReason()
        if reason < 0 and reason not in self.STALLED:
            what = fem.divergence_text(reason, int(ksp.getIterationNumber()))
            raise FloatingPointError(f"linear solver diverged ({what})")
        return int(ksp.getIterationNumber())


class _SchurProduct:
    """``y = -D (P M^-1 G x)``: the Schur complement's action (a PETSc python matrix)."""

    def __init__(self, ops: _DiscreteProjection):
        self.ops = ops

    def mult(self, mat: Any, x: Any, y: Any) -> None:
        self.ops.G.mult(x, self.ops.du)
        self.ops.D.mult(self.ops.du, y)
        y.scale(-1.0)


class _SharedPC:
    """A preconditioner that applies another, already set-up one (a PETSc python PC)."""

    def __init__(self, pc: Any):
        self.pc = pc

    def apply(self, pc: Any, x: Any, y: Any) -> None:
        self.pc.apply(x, y)
