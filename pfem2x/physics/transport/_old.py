r"""Scalar transport :math:`\partial_t T + V\cdot\nabla T = q + \nabla\cdot(\kappa\nabla T) - cT`.

Each term is present only if the scene's ``[effects]`` list it
(``advection``, ``diffusion``, ``source``, ``reaction``). Frames:

- ``eulerian``: P1 Galerkin, θ-method (``method.theta``), consistent mass,
  optional SUPG (``method.supg``).
- ``characteristic``: characteristic Galerkin, the paper's single-mesh
  Lagrangian comparator (one "particle" per node): every node is traced back
  along the velocity to its foot, ``T^n`` is interpolated there, the source is
  integrated along the path (eq. 2.9); diffusion/reaction implicitly on the mesh.
- ``lagrangian``: PFEM-2 (paper section 3, steps 0-6) on the particle layer.

Periodic meshes (``mesh.periodic``) are supported in every mesh solve through
:class:`pfem2x.periodic.PeriodicConstraint`.
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
from pfem2x.periodic import PeriodicConstraint, PeriodicError
from pfem2x.physics.base import Diverged, Solver
from pfem2x.physics.paths import Box, trace
from pfem2x.pointeval import PointEvaluator
from pfem2x.scene import Scene, SceneError

__all__ = [
    "CharacteristicTransport",
    "EulerianTransport",
    "LagrangianTransport",
    "TransportProblem",
    "make_transport_solver",
]


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

    def active_terms(self) -> list[str]:
        """``["mass", ...]`` plus every effect whose term this problem has."""
        pairs = (
            ("advection", self.velocity),
            ("diffusion", self.kappa),
            ("source", self.source),
            ("reaction", self.reaction),
        )
        return ["mass"] + [eff for eff, term in pairs if term is not None]

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
        self.n_owned_dofs = int(self.V.dofmap.index_map.size_local)
        self._pc: PeriodicConstraint | None = None
        self._substeps_last: tuple[float | None, int] = (None, 0)  # (dt, count) of the last step
        self.case = make_case(scene["scene"]["case"], self)

    # -- helpers shared by the frames ---------------------------------------
    def periodic_constraint(self) -> PeriodicConstraint | None:
        """The periodic P1 constraint of the mesh (``None`` without periodic axes), built once."""
        if not any(self.domain.periodic):
            return None
        if self._pc is None:
            try:
                self._pc = PeriodicConstraint(
                    self.V, self.domain.bounds, self.domain.periodic, self.domain.min_h()
                )
            except PeriodicError as exc:
                raise SceneError(str(exc)) from None
        return self._pc

    def dirichlet_bcs(self) -> tuple[list, Any]:
        """``(bcs, g)``: the Dirichlet condition ``transport.boundary_value`` on the exterior
        facets that are not on a periodic face (``([], None)`` without a boundary value)."""
        p = self.problem
        if p.boundary_value is None:
            return [], None
        mesh = self.domain.mesh
        tdim = mesh.topology.dim
        lo, hi = self.domain.bounds
        per = self.domain.periodic
        tol = 1e-8 * self.domain.min_h()

        def not_periodic(x: np.ndarray) -> np.ndarray:
            keep = np.ones(x.shape[1], dtype=bool)
            for ax, pe in enumerate(per):
                if pe:
                    keep &= np.abs(x[ax] - lo[ax]) > tol
                    keep &= np.abs(x[ax] - hi[ax]) > tol
            return keep

        mesh.topology.create_connectivity(tdim - 1, tdim)
        facets = compat.dolfinx.mesh.locate_entities_boundary(mesh, tdim - 1, not_periodic)
        dofs = compat.dolfinx.fem.locate_dofs_topological(self.V, tdim - 1, facets)
        self.bc_dofs = np.asarray(dofs, dtype=np.int32)
        g = compat.dolfinx.fem.Function(self.V)
        return [compat.dolfinx.fem.dirichletbc(g, dofs)], g

    def substeps(self, t: float, dt: float) -> int:
        """Path sub-steps so that each moves at most ``method.substep_courant`` cells.

        While ``dt`` stays the same the count never decreases: the trapezoidal
        source integral along a path is exact up to an end-point term
        ``h**2/12 [dq/ds]`` that telescopes over consecutive sub-steps only if
        their length ``h`` is the same; a count that follows an unsteady speed
        up and down leaves a residue at every change, which accumulates on the
        particles (the manufactured 1D case at omega = 10 drifted to 4x its error).
        """
        if self.problem.velocity is None:
            return 1
        vmax = max(self.max_velocity(t), self.max_velocity(t + dt))
        c = vmax * dt / (self.scene["method"]["substep_courant"] * self.domain.min_h())
        n = max(1, int(np.ceil(c - 1e-9)))
        last_dt, last_n = self._substeps_last
        if last_dt == dt:
            n = max(n, last_n)
        self._substeps_last = (dt, n)
        return n

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
        d.update(self.case.diagnostics(self, t))
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
            out.update(self.case.metrics(history))
        return out


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
        self.preconditioner = base.scene["method"]["preconditioner"]
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


class EulerianTransport(TransportBase):
    """P1 Galerkin θ-method with consistent mass and optional SUPG.

    The left-hand side is assembled once when the velocity and coefficients
    do not depend on time, otherwise every step.
    """

    name = "transport-eulerian"

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
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
        self.bcs, self.g = self.dirichlet_bcs()
        self.time_dependent_lhs = (
            (not p.steady_velocity and p.velocity is not None)
            or any(c.time_dependent for c in self._coeffs)
            or bool(meth["supg"])
        )
        self.A = None
        self.b = compat.create_vector(self.L)
        self._dt_assembled: float | None = None
        self.system = MeshSystem(self, "gmres" if (vel_1 is not None or meth["supg"]) else "cg")

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
            self.system.set_operator(self.A)
        fem.assemble_vector(self.L, self.b, self.a, self.bcs)
        t1 = time.perf_counter()
        self.system.solve(self.b, self.T)
        t2 = time.perf_counter()
        self.timings["assembly"] += t1 - t0
        self.timings["solve"] += t2 - t1
        if not np.all(np.isfinite(self.T.x.array)):
            raise Diverged(f"field {p.field} is not finite")


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
        self.theta = float(base.scene["method"]["theta"])
        self.dt_c = compat.dolfinx.fem.Constant(mesh, PETSc.ScalarType(1.0))
        self.That = compat.dolfinx.fem.Function(V)
        T = ufl.TrialFunction(V)
        w = ufl.TestFunction(V)
        self.coeffs: list[_Coefficient] = []

        def op(u: Any, new: bool) -> Any:
            out = 0
            if p.kappa is not None:
                kc = _Coefficient(p.kappa, V, base.coords)
                kc.at_new = new
                self.coeffs.append(kc)
                out = out + kc.ufl * ufl.inner(ufl.grad(u), ufl.grad(w)) * ufl.dx
            if p.reaction is not None:
                rc = _Coefficient(p.reaction, V, base.coords)
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


class CharacteristicTransport(TransportBase):
    """Characteristic Galerkin: one Lagrangian point per mesh node (the paper's comparator).

    Each owned node is traced back over ``dt`` with RK2 sub-steps (each at
    most ``method.substep_courant`` cells) to its foot; ``T^n`` (and, for
    θ < 1 with diffusion/reaction, the explicit rate) is interpolated there,
    the source is integrated along the path (eq. 2.9) and, when diffusion or
    reaction is active, the implicit part is solved on the mesh. Periodic
    axes wrap; a path leaving through a closed side stops there and takes
    ``transport.boundary_value`` (if given) at the crossing point and time,
    else ``T^n`` at the crossing point.
    """

    name = "transport-characteristic"

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        p = self.problem
        self.theta = float(scene["method"]["theta"])
        self.source_path = scene["method"]["source_integration"] == "path"
        self.terms: list[str] = p.active_terms()
        gdim = domain.gdim
        self.nodes = np.ascontiguousarray(self.coords[: self.n_owned_dofs, :gdim])
        lo, hi = np.asarray(domain.bounds, dtype=float).reshape(2, -1)[:, :gdim]
        self.box = Box(lo, hi, np.array(domain.periodic, dtype=bool))
        self.box_domain = domain.kind in ("interval", "rectangle", "box")
        self.evaluator = PointEvaluator(domain, self.V)
        self.implicit = (
            ImplicitPart(self) if (p.kappa is not None or p.reaction is not None) else None
        )
        self.That = self.implicit.That if self.implicit is not None else self.T

    def _velocity(self, x: np.ndarray, t: float) -> np.ndarray:
        return self.problem.velocity_at(x, t)

    def _pull_inside(self, feet: np.ndarray, found: np.ndarray) -> np.ndarray:
        """Bisect unlocated feet back towards their nodes onto the mesh (collective)."""
        a = self.nodes.copy()
        b = feet.copy()
        bad = ~found
        for _ in range(30):
            if not self.comm.allreduce(int(bad.any()), op=MPI.MAX):
                break
            m = 0.5 * (a + b)
            _, ok = self.evaluator.evaluate(m, np.zeros(len(self.T.x.array)))
            a = np.where((bad & ok)[:, None], m, a)
            b = np.where((bad & ~ok)[:, None], m, b)
            bad = bad & ~np.all(np.abs(a - b) <= 1e-9 * self.domain.min_h(), axis=1)
        feet = np.where(found[:, None], feet, a)
        return feet

    def step(self, t: float, dt: float) -> None:
        p = self.problem
        t0 = time.perf_counter()
        t1 = t + dt
        th = self.theta
        n = self.n_owned_dofs
        if p.velocity is not None:
            q = None
            if p.source is not None:
                q = p.source if self.source_path else (lambda x, s: p.source(x, t))
            nsub = self.substeps(t, dt)
            res = trace(self.nodes, t1, -dt, nsub, self._velocity, self.box, q)
            feet, travelled, exited, q_int = res.x, res.travelled, res.exited, res.q_integral
        else:
            nsub = 1
            feet = self.nodes.copy()
            travelled = np.full(n, dt)
            exited = np.zeros(n, dtype=bool)
            q_int = np.zeros(n)
            if p.source is not None:
                q1 = p.source(feet, t1) if self.source_path else p.source(feet, t)
                q_int = 0.5 * dt * (p.source(feet, t) + q1)
        rate = None
        if self.implicit is not None:
            self.implicit.update_coefficients(t, dt)
            rate = self.implicit.explicit_rate()
        vals = self.T.x.array if rate is None else np.stack([self.T.x.array, rate], axis=1)
        out, found = self.evaluator.evaluate(feet, vals)
        if not self.box_domain and not self.comm.allreduce(int(found.all()), op=MPI.MIN):
            feet = self._pull_inside(feet, found)
            out, found = self.evaluator.evaluate(feet, vals)
        Tfoot = out if rate is None else out[:, 0]
        inflow = exited if p.boundary_value is not None else np.zeros(n, dtype=bool)
        # time over which the point is followed: all of dt, unless it entered through
        # a boundary with a prescribed value (then from the crossing time on)
        tau = np.where(inflow, travelled, dt)
        That = np.where(inflow, 0.0, Tfoot)
        if inflow.any():
            # crossing times, rounded to the sub-step grid (one evaluation per sub-step)
            tin = t1 - travelled[inflow]
            That[inflow] = _eval_at_times(p.boundary_value, feet[inflow], tin, t, dt / nsub)
        if p.source is not None:
            rest = tau - travelled  # time spent resting at a closed wall
            if self.source_path:
                That += q_int + rest * p.source(feet, t)
            else:
                That += (1.0 - th) * (q_int + rest * p.source(feet, t))
                That += th * tau * p.source(self.nodes, t1)
        if rate is not None:
            That += (1.0 - th) * tau * out[:, 1]
        self.That.x.array[:n] = That
        self.That.x.scatter_forward()
        t2 = time.perf_counter()
        self.timings["particles"] += t2 - t0
        if self.implicit is not None:
            self.implicit.solve(t, dt, self.T)
            self.timings["solve"] += time.perf_counter() - t2
        if not np.all(np.isfinite(self.T.x.array)):
            raise Diverged(f"field {p.field} is not finite")


def _velocity_at_times(
    p: TransportProblem, x: np.ndarray, times: np.ndarray, t0: float, h: float
) -> np.ndarray:
    """Velocity at points ``x``, each at its own time rounded to the grid ``t0 + k h``."""
    return np.stack([_eval_at_times(e, x, times, t0, h) for e in p.velocity], axis=1)


def _eval_at_times(
    e: Expression, x: np.ndarray, times: np.ndarray, t0: float, h: float
) -> np.ndarray:
    """``e`` at points ``x``, each at its own time rounded to the grid ``t0 + k h``."""
    if "t" not in e.names:
        return e(x, t0)
    out = np.empty(len(x))
    uniq, inv = np.unique(t0 + h * np.round((times - t0) / h), return_inverse=True)
    for k, tk in enumerate(uniq):
        sel = inv == k
        out[sel] = e(x[sel], float(tk))
    return out


class LagrangianTransport(TransportBase):
    r"""PFEM-2 (paper section 3): the field lives on particles, the mesh only projects.

    One step:

    0. (for θ < 1 with diffusion/reaction) add the explicit rate
       :math:`(1-\theta)\Delta t\,D^n(x_p^n)` to the particles;
    1. move the particles along the streamlines (X-IVAS, eq. 2.10 with θ = 0):
       RK2 sub-steps of at most ``method.substep_courant`` cells through the P1
       velocity for a steady velocity, through ``V(x, s)`` at the sub-step times
       for an unsteady one (the velocity is known at all times);
    2. source along the path: ``method.source_integration = "path"`` integrates
       ``q(x_p(s), s)`` at the sub-step times; ``"theta"`` is eq. (2.9),
       ``(1-θ) ∫ q(x_p(s), t^n) ds + θ Δt q(x_p^{n+1}, t^{n+1})``;
    3. project the particles to P1 (``method.projection``);
    4. only with diffusion or reaction: solve the implicit part on the mesh;
       with a Dirichlet ``boundary_value``: impose it on the boundary nodes;
    5. add the increment δT to the particles (never overwrite them);
    6. add/remove particles to keep every cell within
       ``method.min_particles_per_cell`` / ``max_particles_per_cell``.

    A pure-advection (plus source) run assembles and solves nothing.
    """

    name = "transport-lagrangian"

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        from pfem2x import particles as P  # noqa: PLC0415 - numba only for this frame

        self.P = P
        p = self.problem
        meth = scene["method"]
        self.theta = float(meth["theta"])
        self.source_path = meth["source_integration"] == "path"
        self.projection = "linear" if meth["projection"] == "auto" else meth["projection"]
        self.terms: list[str] = p.active_terms()
        f = p.field
        self.cloud_ = P.Cloud(domain, {f: ()})
        P.seed_cells(self.cloud_, meth["particles_per_cell"], seed=meth["seed"])
        # particles carry the exact initial field (its sub-cell shape), the mesh its interpolant
        self.cloud_.field(f)[:] = p.initial(self.cloud_.x, 0.0)
        self.implicit = (
            ImplicitPart(self) if (p.kappa is not None or p.reaction is not None) else None
        )
        self.That = self.implicit.That if self.implicit is not None else self.T
        if self.implicit is not None:
            self.bcs, self.g = self.implicit.bcs, self.implicit.g
        else:
            self.bcs, self.g = self.dirichlet_bcs()
        self.dT = compat.dolfinx.fem.Function(self.V)
        self.vel_n = None  # steady velocity: its P1 interpolant (the fused move kernel)
        if p.velocity is not None and p.steady_velocity:
            Vv = compat.function_space(domain.mesh, 1, (domain.gdim,))
            self.vel_n = compat.dolfinx.fem.Function(Vv)
            interpolate_expr(self.vel_n, p.velocity, 0.0, self.coords)
        self.step_count = 0
        self.last_projection: Any = None
        self.last_population: Any = None

    def cloud(self) -> Any:
        """The particle cloud (:class:`pfem2x.particles.Cloud`)."""
        return self.cloud_

    def diagnostics(self, t: float) -> dict[str, float]:
        d = super().diagnostics(t)
        d["particles"] = float(self.cloud_.global_count())
        return d

    def _inflow_dofs(self, t: float) -> np.ndarray:
        """Boundary-value dofs where the velocity points into the domain (box domains)."""
        dofs = self.bc_dofs
        p = self.problem
        if p.velocity is None or self.domain.kind not in ("interval", "rectangle", "box"):
            return dofs
        gdim = self.domain.gdim
        x = self.coords[dofs, :gdim]
        v = p.velocity_at(x, t)
        speed = np.linalg.norm(v, axis=1)
        back = x - 1e-3 * self.domain.min_h() * v / np.maximum(speed, 1e-300)[:, None]
        lo, hi = np.asarray(self.domain.bounds, dtype=float).reshape(2, -1)[:, :gdim]
        box = Box(lo, hi, np.array(self.domain.periodic, dtype=bool))
        return dofs[(speed > 0) & (box.exit_fraction(x, back) < 1.0)]

    def _average_periodic(self, u: Any) -> None:
        """Give identified periodic nodes the mean of their one-sided projections."""
        pc = self.periodic_constraint()
        if pc is None:
            return
        xr = pc.restrict(compat.petsc_vec(u))
        pc.expand(xr, compat.petsc_vec(u))
        u.x.scatter_forward()

    def step(self, t: float, dt: float) -> None:
        P = self.P
        p = self.problem
        meth = self.scene["method"]
        c = self.cloud_
        f = p.field
        th = self.theta
        t0 = time.perf_counter()
        t1 = t + dt
        self.step_count += 1
        # 0. explicit diffusion/reaction rate at the start of the path
        if self.implicit is not None:
            self.implicit.update_coefficients(t, dt)
            rate = self.implicit.explicit_rate()
            if rate is not None:
                c.field(f)[:] += (1.0 - th) * dt * P.evaluate(c, rate)
        # 1-2. X-IVAS move with the explicit source integral along the path
        if p.velocity is not None:
            src = p.source
            if src is None:
                qf = None
            elif self.source_path:  # q at the sub-step times: uniform sub-steps, few distinct times

                def qf(x: np.ndarray, s: Any) -> np.ndarray:
                    return _eval_at_times(src, x, np.broadcast_to(s, (len(x),)), t, 1e-9 * dt)
            else:  # eq. 2.9: explicit part frozen at t^n

                def qf(x: np.ndarray, s: Any) -> np.ndarray:
                    return src(x, t)

            vel: Any = self.vel_n
            if not p.steady_velocity:  # the streamline of V(x, s) at the sub-step times
                pv = p

                def vel(x: np.ndarray, s: Any) -> np.ndarray:
                    return _velocity_at_times(pv, x, np.broadcast_to(s, (len(x),)), t, 1e-9 * dt)

            P.advect(
                c,
                vel,
                dt,
                t=t,
                courant=meth["substep_courant"],
                gradient_courant=meth["substep_gradient"],
                substeps=self.substeps(t, dt)
                if (src is not None or vel is not self.vel_n)
                else None,
                source=qf,
                source_field=f if src is not None else None,
                source_scale=1.0 if self.source_path else 1.0 - th,
            )
        elif p.source is not None:
            w0 = 0.5 if self.source_path else 1.0 - th
            c.field(f)[:] += w0 * dt * p.source(c.x, t)
            c.field(f)[:] += (1.0 - w0) * dt * p.source(c.x, t1)
        if p.source is not None and p.velocity is not None and not self.source_path:
            c.field(f)[:] += th * dt * p.source(c.x, t1)
        # 3. projection to the mesh
        self.last_projection = P.project(
            c, f, self.That, method=self.projection, empty="neighbours"
        )
        self._average_periodic(self.That)
        t2 = time.perf_counter()
        self.timings["particles"] += t2 - t0
        # 4-5. implicit correction on the mesh, increment back to the particles
        correct = False
        if self.implicit is not None:
            self.implicit.solve(t, dt, self.T)
            correct = True
        elif self.g is not None:
            # pure transport: the boundary value enters at inflow nodes only
            dofs = self._inflow_dofs(t1)
            interpolate_expr(self.g, p.boundary_value, t1, self.coords)
            self.T.x.array[dofs] = self.g.x.array[dofs]
            correct = True
        t3 = time.perf_counter()
        self.timings["solve"] += t3 - t2
        if correct:
            self.dT.x.array[:] = self.T.x.array - self.That.x.array
            P.add_increment(c, f, self.dT)
        # 6. population control
        nmin, nmax = meth["min_particles_per_cell"], meth["max_particles_per_cell"]
        if nmin > 0 or nmax > 0:
            self.last_population = P.rebalance(
                c, nmin, nmax, seed=meth["seed"] + self.step_count, fallback={f: self.T}
            )
        self.timings["particles"] += time.perf_counter() - t3
        bad = 0 if np.all(np.isfinite(c.field(f))) else 1
        if self.comm.allreduce(bad, op=MPI.MAX):
            raise Diverged(f"particle field {f} is not finite")


def make_transport_solver(scene: Scene, domain: Domain) -> Solver:
    """The transport solver of the scene's frame."""
    frame = scene.frame
    if frame == "eulerian":
        return EulerianTransport(scene, domain)
    if frame == "characteristic":
        return CharacteristicTransport(scene, domain)
    if frame == "lagrangian":
        return LagrangianTransport(scene, domain)
    raise SceneError(f"method.frame: the {frame!r} transport frame is not available yet")
