"""The characteristic transport frame (``method.frame = "characteristic"``).

Characteristic Galerkin, the paper's single-mesh Lagrangian comparator: one
"particle" per mesh node, traced back to its foot every step (see
:class:`CharacteristicTransport`).

Scene keys this frame reads (besides the problem's ``transport.*`` and ``[effects]``):

=============================  ===========================================================
key                            effect in this frame
=============================  ===========================================================
``method.theta``               θ of the diffusion/reaction part and (``theta``) the source
``method.source_integration``  ``path``: q along the path at the sub-step times;
                               ``theta``: eq. 2.9
``method.substep_courant``     cells per RK2 sub-step of the traced paths
``method.preconditioner``      of the implicit mesh solve (diffusion / reaction)
=============================  ===========================================================

Ignored here: ``method.supg``, ``method.projection``, ``method.substep_gradient``
and the particle-count keys.
"""

from __future__ import annotations

import numpy as np

from pfem2x.compat import MPI
from pfem2x.mesh import Domain
from pfem2x.physics.paths import Box, trace
from pfem2x.physics.transport.implicit import ImplicitPart
from pfem2x.physics.transport.problem import TransportBase, eval_at_times
from pfem2x.pointeval import PointEvaluator
from pfem2x.scene import Scene

__all__ = ["CharacteristicTransport"]


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
    checkpoint_state = ("That",)

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        p = self.problem
        self.theta = float(scene.method.theta)
        self.source_path = scene.method.source_integration == "path"
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
        with self.timer("particles"):
            self._trace_back(t, dt)
        if self.implicit is not None:
            with self.timer("solve"):
                self.implicit.solve(t, dt, self.T)
        self.require_finite(f"field {p.field}", self.T.x.array)

    def _trace_back(self, t: float, dt: float) -> None:
        """``That`` at the owned nodes: values at the feet plus the path's source integral."""
        p = self.problem
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
            That[inflow] = eval_at_times(p.boundary_value, feet[inflow], tin, t, dt / nsub)
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
