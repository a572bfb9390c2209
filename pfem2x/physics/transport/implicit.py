"""The mesh part of the transport frames: a periodic-aware linear system, diffusion/reaction."""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem
from pfem2x.compat import PETSc
from pfem2x.physics.transport.problem import Coefficient, TransportBase, interpolate_expr

__all__ = ["ImplicitPart", "MeshSystem"]


class MeshSystem:
    """A linear system on the P1 space, solved on the periodic-reduced space when needed.

    Parameters
    ----------
    base:
        The transport solver (for the periodic constraint and the scene's preconditioner).
    kind:
        ``cg`` or ``gmres`` (see :class:`pfem2x.fem.LinearSolver`).
    """

    def __init__(self, base: TransportBase, kind: str):
        self.pc = base.periodic_constraint()
        self.kind = kind
        self.preconditioner = base.scene.method.preconditioner
        self.solver: fem.LinearSolver | None = None
        self.Ar: Any = None

    def set_operator(self, A: Any) -> None:
        """Use the (re-)assembled full-space matrix ``A``."""
        op = A
        if self.pc is not None:
            self.Ar = self.pc.reduce_matrix(A, self.Ar)
            op = self.Ar
        if self.solver is None:
            self.solver = fem.LinearSolver(op, self.kind, self.preconditioner)
        else:
            self.solver.set_operator(op)

    def solve(self, b: Any, u: Any) -> None:
        """Solve for the Function ``u`` given the full-space right-hand side ``b``."""
        assert self.solver is not None
        if self.pc is not None:
            br = self.pc.reduce_vector(b)
            self.solver.solve(br, self.pc.xr)
            self.pc.expand(self.pc.xr, compat.petsc_vec(u))
        else:
            self.solver.solve(b, compat.petsc_vec(u))
        u.x.scatter_forward()


class ImplicitPart:
    r"""The mesh part of the Lagrangian frames: diffusion and reaction.

    With :math:`A = K_\kappa + M_c` (diffusion stiffness + reaction mass) it
    solves :math:`(M + \theta\Delta t A)\,T^{n+1} = M\hat T` with the Dirichlet
    condition at :math:`t^{n+1}`, and (for :math:`\theta < 1`) gives the
    explicit rate :math:`D^n = -M_L^{-1} A T^n` (lumped mass, no solve) that
    the frames add at the foot of each path, so that
    :math:`T^{n+1} - \theta\Delta t\,L T^{n+1} = [T^n + (1-\theta)\Delta t\,L T^n]_{foot}`.

    Parameters
    ----------
    base:
        The transport solver (``T``, ``V``, problem, scene).
    """

    def __init__(self, base: TransportBase):
        p = base.problem
        V = base.V
        mesh = base.domain.mesh
        self.base = base
        self.theta = float(base.scene.method.theta)
        self.dt_c = compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        self.That = compat.dolfinx.fem.Function(V)
        T = ufl.TrialFunction(V)
        w = ufl.TestFunction(V)
        self.coeffs: list[Coefficient] = []

        def op(u: Any, new: bool) -> Any:
            out = 0
            if p.kappa is not None:
                kc = Coefficient(p.kappa, V, base.coords)
                kc.at_new = new
                self.coeffs.append(kc)
                out = out + kc.ufl * ufl.inner(ufl.grad(u), ufl.grad(w)) * ufl.dx
            if p.reaction is not None:
                rc = Coefficient(p.reaction, V, base.coords)
                rc.at_new = new
                self.coeffs.append(rc)
                out = out + rc.ufl * u * w * ufl.dx
            return out

        a = T * w * ufl.dx + self.dt_c * PETSc.ScalarType(self.theta) * op(T, True)
        self.a = compat.form(a)
        self.L = compat.form(self.That * w * ufl.dx)
        self.bcs, self.g = base.dirichlet_bcs()
        self.b = compat.create_vector(self.L)
        self.A: Any = None
        self._dt: float | None = None
        self.time_dependent = any(c.time_dependent for c in self.coeffs)
        self.system = MeshSystem(base, "cg")
        self.D: Any = None
        if self.theta < 1.0:
            self.D = compat.dolfinx.fem.Function(V)
            self.Ld = compat.form(-op(base.T, False))
            self.bd = compat.create_vector(self.Ld)
            one = compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
            lm = compat.form(one * w * ufl.dx)
            self.mlump = compat.create_vector(lm)
            fem.assemble_vector(lm, self.mlump)
            pc = base.periodic_constraint()
            if pc is not None:
                self.mlump_r = pc.P.createVecRight()
                pc.P.multTranspose(self.mlump, self.mlump_r)

    def update_coefficients(self, t: float, dt: float) -> None:
        """Evaluate time-dependent coefficients (explicit ones at ``t``, implicit at ``t+dt``)."""
        for c in self.coeffs:
            if c.time_dependent:
                c.update(t + dt if c.at_new else t)

    def explicit_rate(self) -> np.ndarray | None:
        """Nodal :math:`D^n = -M_L^{-1} A T^n` (owned + ghost entries), ``None`` if θ = 1."""
        if self.D is None:
            return None
        fem.assemble_vector(self.Ld, self.bd)
        pc = self.base.periodic_constraint()
        dv = compat.petsc_vec(self.D)
        if pc is not None:
            br = pc.reduce_vector(self.bd)
            br.pointwiseDivide(br, self.mlump_r)
            pc.expand(br, dv)
        else:
            dv.pointwiseDivide(self.bd, self.mlump)
        self.D.x.scatter_forward()
        return self.D.x.array

    def solve(self, t: float, dt: float, out: Any) -> None:
        """Solve :math:`(M + \\theta\\Delta t A) T^{n+1} = M\\hat T` into ``out`` (``That`` set)."""
        if self.g is not None:
            interpolate_expr(self.g, self.base.problem.boundary_value, t + dt, self.base.coords)
        if self.A is None or self.time_dependent or self._dt != dt:
            self.dt_c.value = dt
            self.A = fem.assemble_matrix(self.a, self.bcs, self.A)
            self._dt = dt
            self.system.set_operator(self.A)
        fem.assemble_vector(self.L, self.b, self.a, self.bcs)
        self.system.solve(self.b, out)
