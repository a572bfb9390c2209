"""The common transport problem: scene data, the P1 field, boundaries, diagnostics.

:class:`TransportProblem` reads the scene; :class:`TransportBase` is what the
three frames share (:mod:`~pfem2x.physics.transport.eulerian`,
:mod:`~pfem2x.physics.transport.characteristic`,
:mod:`~pfem2x.physics.transport.lagrangian`): the P1 space and field, the exact
solution, the periodic constraint, the Dirichlet condition, path sub-steps
and the diagnostics.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.cases import make_case
from pfem2x.compat import MPI, PETSc
from pfem2x.expr import Expression
from pfem2x.mesh import Domain
from pfem2x.periodic import PeriodicConstraint, PeriodicError
from pfem2x.physics.base import Solver, require_finite_input
from pfem2x.scene import Scene, SceneError

__all__ = [
    "Coefficient",
    "TransportBase",
    "TransportProblem",
    "eval_at_times",
    "interpolate_expr",
    "velocity_at_times",
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
        tr = scene.transport
        self.field = tr.field
        self.velocity: list[Expression] | None = (
            scene.vector_expr("transport", "velocity", gdim) if eff.advection else None
        )
        self.kappa = scene.expr("transport", "kappa") if eff.diffusion else None
        self.source = scene.expr("transport", "source") if eff.source else None
        self.reaction = scene.expr("transport", "reaction") if eff.reaction else None
        self.initial = scene.expr("transport", "initial")
        self.exact = scene.expr("transport", "exact") if tr.exact is not None else None
        self.boundary_value = (
            scene.expr("transport", "boundary_value") if tr.boundary_value is not None else None
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


class Coefficient:
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


def velocity_at_times(
    p: TransportProblem, x: np.ndarray, times: np.ndarray, t0: float, h: float
) -> np.ndarray:
    """Velocity at points ``x``, each at its own time rounded to the grid ``t0 + k h``."""
    return np.stack([eval_at_times(e, x, times, t0, h) for e in p.velocity], axis=1)


def eval_at_times(
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


class TransportBase(Solver):
    """Shared set-up of the transport frames: spaces, field, exact solution, diagnostics."""

    checkpoint_state = ("T", "g", "_substeps_last")

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        mesh = domain.mesh
        self.problem = TransportProblem(scene, domain.gdim)
        self.V = compat.function_space(mesh, 1)
        self.coords = self.V.tabulate_dof_coordinates()
        self.T = compat.dolfinx.fem.Function(self.V, name=self.problem.field)
        interpolate_expr(self.T, self.problem.initial, 0.0, self.coords)
        n = self.V.dofmap.index_map.size_local
        require_finite_input(
            self.comm, "transport.initial", self.T.x.array[:n], self.coords[:n, : domain.gdim]
        )
        self._require_finite_inputs(n, domain.gdim)
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
        self.case = make_case(scene.scene.case, self)

    def _require_finite_inputs(self, n: int, gdim: int) -> None:
        """SceneError naming the key of an expression not finite at t = 0 on the owned nodes.

        ExpressionError if one cannot be evaluated there (:func:`~pfem2x.runner.make_solver`
        makes it a SceneError).
        """
        p, x = self.problem, self.coords[:n]
        if p.velocity is not None:
            require_finite_input(
                self.comm, "transport.velocity", p.velocity_at(x, 0.0), x[:, :gdim]
            )
        for key in ("kappa", "source", "reaction", "exact"):  # boundary_value: on the sides
            e = getattr(p, key)
            if e is not None:
                require_finite_input(self.comm, f"transport.{key}", e(x, 0.0), x[:, :gdim])
        if p.boundary_value is not None:  # used on the sides only: evaluated, not checked
            p.boundary_value(x, 0.0)

    def input_report(self, t0: float, t1: float) -> str:
        """The transport expressions not finite on the owned nodes at ``t0``, the step's
        middle or ``t1`` (collective): ``"transport.source is not finite at 81 node(s) at
        t = 0.5"``, or ``""``."""
        p, x = self.problem, self.coords[: self.V.dofmap.index_map.size_local]
        keys = [k for k in ("velocity", "kappa", "source", "reaction") if getattr(p, k) is not None]
        times = (t0, 0.5 * (t0 + t1), t1)
        bad = np.zeros((len(keys), len(times)))
        with np.errstate(all="ignore"):
            for i, k in enumerate(keys):
                for j, t in enumerate(times):
                    v = p.velocity_at(x, t) if k == "velocity" else getattr(p, k)(x, t)
                    bad[i, j] = np.count_nonzero(~np.isfinite(np.asarray(v).reshape(len(x), -1)))
        bad = self.comm.allreduce(bad, op=MPI.SUM)
        found = []
        for i, k in enumerate(keys):
            j = next((j for j in range(len(times)) if bad[i, j] > 0), None)
            if j is not None:
                found.append(f"transport.{k} is not finite at {int(bad[i, j])} node(s) at "
                             f"t = {times[j]:.6g}")  # fmt: skip
        return "; ".join(found)

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
        c = vmax * dt / (self.scene.method.substep_courant * self.domain.min_h())
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
