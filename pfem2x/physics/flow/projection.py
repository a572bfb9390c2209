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
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import ufl

from pfem2x import compat, fem

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
    ):
        self.bcs_u, self.bcs_p = bcs_u, bcs_p
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
        self.L_p0 = (
            compat.form((1.0 / rho) * ufl.dot(f_body, ufl.grad(r)) * dxq)
            if f_body is not None
            else None
        )
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
        #: iteration counts of the last solves, by equation
        self.iterations: dict[str, int] = {}

    def assemble_operator(self) -> None:
        """(Re-)assemble the pressure operator (its density may have changed)."""
        self.A_p = fem.assemble_matrix(self.a_p, self.bcs_p, self.A_p)
        if not self.bcs_p:
            self.nullspace = compat.constant_nullspace(self.A_p)
        if self.p_solver is None:
            self.p_solver = fem.LinearSolver(self.A_p, "cg", self.preconditioner, rtol=self.rtol)
        else:
            self.p_solver.set_operator(self.A_p)

    def solve(self, L: Any, x: Any) -> None:
        """Solve the pressure operator against the right-hand side form ``L`` into ``x``."""
        fem.assemble_vector(L, self.b_p, self.a_p, self.bcs_p)
        if self.nullspace is not None:
            self.nullspace.remove(self.b_p)
        with self.timer("solve"):
            self.iterations["pressure"] = self.p_solver.solve(self.b_p, compat.petsc_vec(x))
            x.x.scatter_forward()

    def solve_increment(self) -> None:
        """The pressure increment ``dp`` from the divergence of ``u_star``."""
        self.solve(self.L_p, self.dp)

    def initial_pressure(self, p: Any) -> None:
        """Hydrostatic start into ``p``: ``div(rho^-1 (grad p - rho g)) = 0``."""
        self.assemble_operator()
        self.solve(self.L_p0, p)

    def assemble_mass(self) -> None:
        """The rho-weighted lumped mass of the current density into :attr:`b_mass`."""
        fem.assemble_vector(self.L_mass, self.b_mass)

    def correct(self, u: Any, p: Any, dt: float, mass_ready: bool = False) -> None:
        """``u = u* - dt M^-1 grad(dp)`` with the velocity conditions; ``p += dp`` (or ``= dp``).

        ``mass_ready``: :attr:`b_mass` already holds the lumped mass of the
        current density (``"momentum"`` correction).
        """
        fem.assemble_vector(self.L_c, self.b_c)
        if self.correction == "velocity":
            mass = self.b_lumped
        else:
            if not mass_ready:
                self.assemble_mass()
            mass = self.b_mass
        n = len(self.b_c.array_r)
        u.x.array[:n] = self.u_star.x.array[:n] - dt * self.b_c.array_r / mass.array_r
        compat.set_bc(compat.petsc_vec(u), self.bcs_u)
        u.x.scatter_forward()
        if self.incremental:
            p.x.array[:] += self.dp.x.array
        else:
            p.x.array[:] = self.dp.x.array
