r"""Scalar transport :math:`\partial_t T + V\cdot\nabla T = q + \nabla\cdot(\kappa\nabla T) - cT`.

Each term is present only if the scene's ``[effects]`` list it
(``advection``, ``diffusion``, ``source``, ``reaction``). Frames:

- ``eulerian``: P1 Galerkin, θ-method (``method.theta``), consistent mass,
  optional SUPG (``method.supg``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem
from pfem2x.compat import MPI, PETSc
from pfem2x.expr import Expression
from pfem2x.mesh import Domain
from pfem2x.physics.base import Diverged, Solver
from pfem2x.scene import Scene, SceneError

__all__ = ["EulerianTransport", "TransportProblem", "make_transport_solver"]


class TransportProblem:
    """The scene's transport data: compiled expressions and active effects.

    Attributes
    ----------
    velocity:
        Component expressions (``None`` without advection).
    kappa, source, reaction:
        Expressions, or ``None`` when the effect is off.
    initial, exact:
        Initial field and (optional) exact solution.
    """

    def __init__(self, scene: Scene, gdim: int):
        eff = scene.effects
        tr = scene["transport"]
        self.field = tr["field"]
        self.velocity: list[Expression] | None = (
            scene.vector_expr("transport", "velocity", gdim) if eff["advection"] else None
        )
        self.kappa = scene.expr("transport", "kappa") if eff["diffusion"] else None
        self.source = scene.expr("transport", "source") if eff["source"] else None
        self.reaction = scene.expr("transport", "reaction") if eff["reaction"] else None
        self.initial = scene.expr("transport", "initial")
        self.exact = scene.expr("transport", "exact") if tr["exact"] is not None else None
        self.boundary_value = (
            scene.expr("transport", "boundary_value") if tr["boundary_value"] is not None else None
        )
        self.steady_velocity = self.velocity is None or all(
            e.constant or "t" not in e.names for e in self.velocity
        )

    def velocity_at(self, x: np.ndarray, t: float) -> np.ndarray:
        """Velocity at points ``x`` (n, ≥gdim) and time ``t``: shape (n, gdim)."""
        if self.velocity is None:
            return np.zeros((x.shape[0], 1))
        return np.stack([e(x, t) for e in self.velocity], axis=1)


def interpolate_expr(
    u: Any, exprs: Expression | list[Expression], t: float, coords: np.ndarray
) -> None:
    """Set a P1 (scalar or vector) function's dofs from expression(s) at time ``t``."""
    if isinstance(exprs, Expression):
        u.x.array[:] = exprs(coords, t)
        return
    arr = u.x.array.reshape(-1, len(exprs))
    for i, e in enumerate(exprs):
        arr[:, i] = e(coords, t)


class _Coefficient:
    """An expression as a UFL coefficient: a Constant if constant, else a P1 Function."""

    def __init__(self, expr: Expression, V: Any, coords: np.ndarray):
        self.expr = expr
        self.coords = coords
        self.time_dependent = "t" in expr.names
        if expr.constant:
            self.ufl = compat.dolfinx.fem.Constant(V.mesh, PETSc.ScalarType(expr.value()))
            self.time_dependent = False
        else:
            self.ufl = compat.dolfinx.fem.Function(V)
            interpolate_expr(self.ufl, expr, 0.0, coords)

    def update(self, t: float) -> None:
        if isinstance(self.ufl, compat.dolfinx.fem.Function):
            interpolate_expr(self.ufl, self.expr, t, self.coords)
        else:
            self.ufl.value = self.expr.value()


class TransportBase(Solver):
    """Shared set-up of the transport frames: spaces, field, exact solution, diagnostics."""

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        mesh = domain.mesh
        self.problem = TransportProblem(scene, domain.gdim)
        self.V = compat.function_space(mesh, 1)
        self.coords = self.V.tabulate_dof_coordinates()
        self.T = compat.dolfinx.fem.Function(self.V, name=self.problem.field)
        interpolate_expr(self.T, self.problem.initial, 0.0, self.coords)
        self.dx = ufl.dx(domain=mesh)
        self._err = compat.dolfinx.fem.Function(self.V)
        self._err_form = compat.form(self._err**2 * self.dx)
        self._one = compat.form(compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0)) * self.dx)
        self._mass = compat.form(self.T * self.dx)
        self.volume = self._assemble_scalar(self._one)
        self._vel_nodes = None

    def _assemble_scalar(self, f: Any) -> float:
        return float(self.comm.allreduce(compat.dolfinx.fem.assemble_scalar(f), op=MPI.SUM))

    def max_velocity(self, t: float) -> float:
        if self.problem.velocity is None:
            return 0.0
        v = self.problem.velocity_at(self.coords, t)
        local = float(np.max(np.linalg.norm(v, axis=1))) if len(v) else 0.0
        return float(self.comm.allreduce(local, op=MPI.MAX))

    def fields(self) -> dict[str, Any]:
        return {self.problem.field: self.T}

    def diagnostics(self, t: float) -> dict[str, float]:
        arr = self.T.x.array
        d = {
            "min": float(self.comm.allreduce(arr.min() if len(arr) else np.inf, op=MPI.MIN)),
            "max": float(self.comm.allreduce(arr.max() if len(arr) else -np.inf, op=MPI.MAX)),
            "integral": self._assemble_scalar(self._mass),
        }
        if self.problem.exact is not None:
            self._err.x.array[:] = arr - self.problem.exact(self.coords, t)
            # domain RMS of the error: ||T_h - T||_L2 / sqrt(|Omega|)
            d["l2_error"] = float(
                np.sqrt(max(self._assemble_scalar(self._err_form), 0.0) / self.volume)
            )
        return d

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if history and "l2_error" in history[-1]:
            errs = [h["l2_error"] for h in history if "l2_error" in h]
            out["l2_error_time_avg"] = float(np.mean(errs))
            out["l2_error_final"] = float(errs[-1])
        if history:
            out["min_final"] = history[-1]["min"]
            out["max_final"] = history[-1]["max"]
            out["integral_change"] = float(history[-1]["integral"] - history[0]["integral"])
        return out


class EulerianTransport(TransportBase):
    """P1 Galerkin θ-method with consistent mass and optional SUPG.

    The left-hand side is assembled once when the velocity and coefficients
    do not depend on time, otherwise every step.
    """

    name = "transport-eulerian"

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        if any(domain.periodic):
            raise SceneError(
                "mesh.periodic: the eulerian transport frame does not support periodic meshes yet"
            )
        p = self.problem
        meth = scene["method"]
        theta = meth["theta"]
        mesh = domain.mesh
        V = self.V
        gdim = domain.gdim
        Tn = self.T
        T = ufl.TrialFunction(V)
        w = ufl.TestFunction(V)
        self.dt_c = compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        dt = self.dt_c
        self.terms: list[str] = ["mass"]
        self._coeffs: list[_Coefficient] = []
        th = PETSc.ScalarType(theta)

        def op(u: Any, ww: Any, vel: Any | None, kap: Any | None, rea: Any | None) -> Any:
            out = 0
            if vel is not None:
                out = out + ufl.dot(vel, ufl.grad(u)) * ww * ufl.dx
            if kap is not None:
                out = out + kap * ufl.inner(ufl.grad(u), ufl.grad(w)) * ufl.dx
            if rea is not None:
                out = out + rea * u * ww * ufl.dx
            return out

        vel_n = vel_1 = kap = rea = None
        self.Vv = None
        if p.velocity is not None:
            self.terms.append("advection")
            self.Vv = compat.function_space(mesh, 1, (gdim,))
            vel_n = compat.dolfinx.fem.Function(self.Vv)
            vel_1 = compat.dolfinx.fem.Function(self.Vv)
            interpolate_expr(vel_n, p.velocity, 0.0, self.coords)
            interpolate_expr(vel_1, p.velocity, 0.0, self.coords)
        self.vel_n, self.vel_1 = vel_n, vel_1
        if p.kappa is not None:
            self.terms.append("diffusion")
            kap_c = _Coefficient(p.kappa, V, self.coords)
            self._coeffs.append(kap_c)
            kap = kap_c.ufl
        if p.reaction is not None:
            self.terms.append("reaction")
            rea_c = _Coefficient(p.reaction, V, self.coords)
            self._coeffs.append(rea_c)
            rea = rea_c.ufl
        # Test function, optionally SUPG-weighted with the new velocity.
        wt = w
        if meth["supg"] and vel_1 is not None:
            self.terms.append("supg")
            h = ufl.CellDiameter(mesh)
            vnorm = ufl.sqrt(ufl.dot(vel_1, vel_1)) + 1e-12
            tau = 1.0 / ufl.sqrt((2.0 / dt) ** 2 + (2.0 * vnorm / h) ** 2)
            wt = w + tau * ufl.dot(vel_1, ufl.grad(w))
        a = T * wt * ufl.dx
        L = Tn * wt * ufl.dx
        lhs_op = op(T, wt, vel_1, kap, rea)
        rhs_op = op(Tn, wt, vel_n, kap, rea)
        if lhs_op != 0:
            a = a + dt * th * lhs_op
            L = L - dt * (1 - th) * rhs_op
        self.q_n = self.q_1 = None
        if p.source is not None:
            self.terms.append("source")
            self.q_n = compat.dolfinx.fem.Function(V)
            self.q_1 = compat.dolfinx.fem.Function(V)
            L = L + dt * ((1 - th) * self.q_n + th * self.q_1) * wt * ufl.dx
        self.a = compat.form(a)
        self.L = compat.form(L)
        self.bcs = []
        if p.boundary_value is not None:
            tdim = mesh.topology.dim
            mesh.topology.create_connectivity(tdim - 1, tdim)
            facets = compat.dolfinx.mesh.exterior_facet_indices(mesh.topology)
            dofs = compat.dolfinx.fem.locate_dofs_topological(V, tdim - 1, facets)
            self.g = compat.dolfinx.fem.Function(V)
            self.bcs = [compat.dolfinx.fem.dirichletbc(self.g, dofs)]
        self.time_dependent_lhs = (
            (not p.steady_velocity and p.velocity is not None)
            or any(c.time_dependent for c in self._coeffs)
            or bool(meth["supg"])
        )
        self.A = None
        self.b = compat.create_vector(self.L)
        self.solver: fem.LinearSolver | None = None
        self._dt_assembled: float | None = None
        self.kind = "gmres" if (vel_1 is not None or meth["supg"]) else "cg"

    def step(self, t: float, dt: float) -> None:
        p = self.problem
        t0 = time.perf_counter()
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
            if self.solver is None:
                self.solver = fem.LinearSolver(
                    self.A, self.kind, self.scene["method"]["preconditioner"]
                )
            else:
                self.solver.set_operator(self.A)
        fem.assemble_vector(self.L, self.b, self.a, self.bcs)
        t1 = time.perf_counter()
        self.solver.solve(self.b, compat.petsc_vec(self.T))
        self.T.x.scatter_forward()
        t2 = time.perf_counter()
        self.timings["assembly"] += t1 - t0
        self.timings["solve"] += t2 - t1
        if not np.all(np.isfinite(self.T.x.array)):
            raise Diverged(f"field {p.field} is not finite")


def make_transport_solver(scene: Scene, domain: Domain) -> Solver:
    """The transport solver of the scene's frame."""
    frame = scene.frame
    if frame == "eulerian":
        return EulerianTransport(scene, domain)
    raise SceneError(f"method.frame: the {frame!r} transport frame is not available yet")
