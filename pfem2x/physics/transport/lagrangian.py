"""The PFEM-2 transport frame (``method.frame = "lagrangian"``).

The field lives on particles; the mesh only projects (see :class:`LagrangianTransport`).

Scene keys this frame reads (besides the problem's ``transport.*`` and ``[effects]``):

=================================  ========================================================
key                                effect in this frame
=================================  ========================================================
``method.particles_per_cell``      particles seeded per cell
``method.min_particles_per_cell``  step 6: cells with fewer get particles (0: off)
``method.max_particles_per_cell``  step 6: cells with more lose particles (0: off)
``method.seed``                    seeding and population control
``method.projection``              step 3 (``auto`` = ``linear``)
``method.substep_courant``         step 1: cells per X-IVAS sub-step
``method.substep_gradient``        step 1: turning per sub-step (P1 velocity)
``method.source_integration``      step 2: ``path`` or ``theta`` (eq. 2.9)
``method.theta``                   θ of the implicit part and of the ``theta`` source
``method.preconditioner``          of the implicit mesh solve (diffusion / reaction)
=================================  ========================================================

Ignored here: ``method.supg``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.mesh import Domain
from pfem2x.physics.paths import Box
from pfem2x.physics.transport.implicit import ImplicitPart
from pfem2x.physics.transport.problem import (
    TransportBase,
    eval_at_times,
    interpolate_expr,
    velocity_at_times,
)
from pfem2x.scene import Scene

__all__ = ["LagrangianTransport"]


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
    checkpoint_state = ("That", "dT", "vel_n", "step_count")

    def __init__(self, scene: Scene, domain: Domain):
        super().__init__(scene, domain)
        from pfem2x import particles as P  # noqa: PLC0415 - numba only for this frame

        self.P = P
        p = self.problem
        meth = scene.method
        self.theta = float(meth.theta)
        self.source_path = meth.source_integration == "path"
        self.projection = "linear" if meth.projection == "auto" else meth.projection
        self.terms: list[str] = p.active_terms()
        f = p.field
        self.cloud_ = P.Cloud(domain, {f: ()})
        P.seed_cells(self.cloud_, meth.particles_per_cell, seed=meth.seed)
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
        meth = self.scene.method
        c = self.cloud_
        f = p.field
        self.step_count += 1
        with self.timer("particles"):
            self._move(t, dt)
            # 3. projection to the mesh
            self.last_projection = P.project(
                c, f, self.That, method=self.projection, empty="neighbours"
            )
            self._average_periodic(self.That)
        # 4-5. implicit correction on the mesh, increment back to the particles
        with self.timer("solve"):
            correct = self._mesh_correction(t, dt)
        with self.timer("particles"):
            if correct:
                self.dT.x.array[:] = self.T.x.array - self.That.x.array
                P.add_increment(c, f, self.dT)
            # 6. population control
            nmin, nmax = meth.min_particles_per_cell, meth.max_particles_per_cell
            if nmin > 0 or nmax > 0:
                self.last_population = P.rebalance(
                    c, nmin, nmax, seed=meth.seed + self.step_count, fallback={f: self.T}
                )
        self.require_finite(f"particle field {f}", c.field(f))

    def _move(self, t: float, dt: float) -> None:
        """Steps 0-2: explicit rate, X-IVAS move with the source integral along the path."""
        P = self.P
        p = self.problem
        c = self.cloud_
        f = p.field
        th = self.theta
        t1 = t + dt
        # 0. explicit diffusion/reaction rate at the start of the path
        if self.implicit is not None:
            self.implicit.update_coefficients(t, dt)
            rate = self.implicit.explicit_rate()
            if rate is not None:
                c.field(f)[:] += (1.0 - th) * dt * P.evaluate(c, rate)
        # 1-2. X-IVAS move with the explicit source integral along the path
        if p.velocity is not None:
            self._advect(t, dt)
        elif p.source is not None:
            w0 = 0.5 if self.source_path else 1.0 - th
            c.field(f)[:] += w0 * dt * p.source(c.x, t)
            c.field(f)[:] += (1.0 - w0) * dt * p.source(c.x, t1)
        if p.source is not None and p.velocity is not None and not self.source_path:
            c.field(f)[:] += th * dt * p.source(c.x, t1)

    def _advect(self, t: float, dt: float) -> None:
        """Steps 1-2 with a velocity: the move kernel with the source along the path."""
        p = self.problem
        meth = self.scene.method
        src = p.source
        if src is None:
            qf = None
        elif self.source_path:  # q at the sub-step times: uniform sub-steps, few distinct times

            def qf(x: np.ndarray, s: Any) -> np.ndarray:
                return eval_at_times(src, x, np.broadcast_to(s, (len(x),)), t, 1e-9 * dt)
        else:  # eq. 2.9: explicit part frozen at t^n

            def qf(x: np.ndarray, s: Any) -> np.ndarray:
                return src(x, t)

        vel: Any = self.vel_n
        if not p.steady_velocity:  # the streamline of V(x, s) at the sub-step times
            pv = p

            def vel(x: np.ndarray, s: Any) -> np.ndarray:
                return velocity_at_times(pv, x, np.broadcast_to(s, (len(x),)), t, 1e-9 * dt)

        self.P.advect(
            self.cloud_,
            vel,
            dt,
            t=t,
            courant=meth.substep_courant,
            gradient_courant=meth.substep_gradient,
            substeps=self.substeps(t, dt) if (src is not None or vel is not self.vel_n) else None,
            source=qf,
            source_field=p.field if src is not None else None,
            source_scale=1.0 if self.source_path else 1.0 - self.theta,
        )

    def _mesh_correction(self, t: float, dt: float) -> bool:
        """Step 4: ``T`` from ``That`` on the mesh; ``False`` when nothing is to be done."""
        p = self.problem
        if self.implicit is not None:
            self.implicit.solve(t, dt, self.T)
            return True
        if self.g is not None:
            # pure transport: the boundary value enters at inflow nodes only
            dofs = self._inflow_dofs(t + dt)
            interpolate_expr(self.g, p.boundary_value, t + dt, self.coords)
            self.T.x.array[dofs] = self.g.x.array[dofs]
            return True
        return False
