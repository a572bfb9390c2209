r"""The Eulerian transport frame (``method.frame = "eulerian"``): P1 Galerkin θ-method.

:math:`(T^{n+1} - T^n)/\Delta t + \theta L T^{n+1} + (1-\theta) L T^n = \theta q^{n+1} +
(1-\theta) q^n` with :math:`L T = V\cdot\nabla T - \nabla\cdot(\kappa\nabla T) + cT`,
consistent mass, the Dirichlet ``transport.boundary_value`` on the non-periodic
boundary.

Scene keys this frame reads (besides the problem's ``transport.*`` and ``[effects]``):

==========================  ==============================================================
key                         effect in this frame
==========================  ==============================================================
``method.theta``            θ of the time discretisation (1/2: Crank–Nicolson)
``method.supg``             SUPG test functions with the new velocity (left side every step)
``method.preconditioner``   of the mesh solve (cg when symmetric, else GMRES)
==========================  ==============================================================

Ignored here: the particle keys (``particles_per_cell``, ``projection``,
``substep_*``, ``seed``, ...) and ``method.source_integration``.
"""

from __future__ import annotations

from typing import Any

import ufl

from pfem2x import compat, fem
from pfem2x.compat import PETSc
from pfem2x.mesh import Domain
from pfem2x.physics.transport.implicit import MeshSystem
from pfem2x.physics.transport.problem import Coefficient, TransportBase, interpolate_expr
from pfem2x.scene import Scene

__all__ = ["EulerianTransport"]


class EulerianTransport(TransportBase):
    """P1 Galerkin θ-method with consistent mass and optional SUPG.

    The left-hand side is assembled once when the velocity and coefficients
    do not depend on time, otherwise every step.
    """

    name = "transport-eulerian"
    checkpoint_state = ("vel_n", "vel_1", "q_n", "q_1")

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        p = self.problem
        meth = scene.method
        self.dt_c = compat.dolfinx.fem.Constant(domain.mesh, PETSc.ScalarType(1.0))
        self.terms: list[str] = ["mass"]
        self._coeffs: list[Coefficient] = []
        kap, rea = self._coefficients()
        a, L = self._forms(kap, rea)
        self.a = compat.form(a)
        self.L = compat.form(L)
        self.bcs, self.g = self.dirichlet_bcs()
        self.time_dependent_lhs = (
            (not p.steady_velocity and p.velocity is not None)
            or any(c.time_dependent for c in self._coeffs)
            or bool(meth.supg)
        )
        self.A = None
        self.b = compat.create_vector(self.L)
        self._dt_assembled: float | None = None
        kind = "gmres" if (self.vel_1 is not None or meth.supg) else "cg"
        self.system = MeshSystem(self, kind)

    def _coefficients(self) -> tuple[Any, Any]:
        """Velocity at both ends of the step, diffusivity and reaction (``None``: off)."""
        p = self.problem
        mesh = self.domain.mesh
        vel_n = vel_1 = kap = rea = None
        self.Vv = None
        if p.velocity is not None:
            self.terms.append("advection")
            self.Vv = compat.function_space(mesh, 1, (self.domain.gdim,))
            vel_n = compat.dolfinx.fem.Function(self.Vv)
            vel_1 = compat.dolfinx.fem.Function(self.Vv)
            interpolate_expr(vel_n, p.velocity, 0.0, self.coords)
            interpolate_expr(vel_1, p.velocity, 0.0, self.coords)
        self.vel_n, self.vel_1 = vel_n, vel_1
        if p.kappa is not None:
            self.terms.append("diffusion")
            kap_c = Coefficient(p.kappa, self.V, self.coords)
            self._coeffs.append(kap_c)
            kap = kap_c.ufl
        if p.reaction is not None:
            self.terms.append("reaction")
            rea_c = Coefficient(p.reaction, self.V, self.coords)
            self._coeffs.append(rea_c)
            rea = rea_c.ufl
        return kap, rea

    def _forms(self, kap: Any, rea: Any) -> tuple[Any, Any]:
        """The θ-method's bilinear and linear forms (UFL)."""
        p = self.problem
        meth = self.scene.method
        V, Tn, dt = self.V, self.T, self.dt_c
        vel_n, vel_1 = self.vel_n, self.vel_1
        T = ufl.TrialFunction(V)
        w = ufl.TestFunction(V)
        th = PETSc.ScalarType(meth.theta)

        def op(u: Any, ww: Any, vel: Any | None) -> Any:
            out = 0
            if vel is not None:
                out = out + ufl.dot(vel, ufl.grad(u)) * ww * ufl.dx
            if kap is not None:
                out = out + kap * ufl.inner(ufl.grad(u), ufl.grad(w)) * ufl.dx
            if rea is not None:
                out = out + rea * u * ww * ufl.dx
            return out

        # Test function, optionally SUPG-weighted with the new velocity.
        wt = w
        if meth.supg and vel_1 is not None:
            self.terms.append("supg")
            h = ufl.CellDiameter(self.domain.mesh)
            vnorm = ufl.sqrt(ufl.dot(vel_1, vel_1)) + 1e-12
            tau = 1.0 / ufl.sqrt((2.0 / dt) ** 2 + (2.0 * vnorm / h) ** 2)
            wt = w + tau * ufl.dot(vel_1, ufl.grad(w))
        a = T * wt * ufl.dx
        L = Tn * wt * ufl.dx
        lhs_op = op(T, wt, vel_1)
        rhs_op = op(Tn, wt, vel_n)
        if lhs_op != 0:
            a = a + dt * th * lhs_op
            L = L - dt * (1 - th) * rhs_op
        self.q_n = self.q_1 = None
        if p.source is not None:
            self.terms.append("source")
            self.q_n = compat.dolfinx.fem.Function(V)
            self.q_1 = compat.dolfinx.fem.Function(V)
            L = L + dt * ((1 - th) * self.q_n + th * self.q_1) * wt * ufl.dx
        return a, L

    def step(self, t: float, dt: float) -> None:
        p = self.problem
        with self.timer("assembly"):
            self.dt_c.value = dt
            if p.velocity is not None and not p.steady_velocity:
                interpolate_expr(self.vel_n, p.velocity, t, self.coords)
                interpolate_expr(self.vel_1, p.velocity, t + dt, self.coords)
            for c in self._coeffs:
                if c.time_dependent:
                    c.update(t + dt)
            if self.q_n is not None:
                interpolate_expr(self.q_n, p.source, t, self.coords)
                interpolate_expr(self.q_1, p.source, t + dt, self.coords)
            if self.bcs:
                interpolate_expr(self.g, p.boundary_value, t + dt, self.coords)
            if self.A is None or self.time_dependent_lhs or self._dt_assembled != dt:
                self.A = fem.assemble_matrix(self.a, self.bcs, self.A)
                self._dt_assembled = dt
                self.system.set_operator(self.A)
            fem.assemble_vector(self.L, self.b, self.a, self.bcs)
        with self.timer("solve"):
            self.system.solve(self.b, self.T)
        self.require_finite(f"field {p.field}", self.T.x.array)
