r"""Particle–mesh transfers of the PFEM-2 flow frame (:mod:`~pfem2x.physics.flow.pfem2`).

Step 2's velocity projection (plain, mass-weighted, affine), step 4's increment, the cell phase
fraction of the particles and the volume-keeping shift of the level set
``dist``, and step 5's population control (new particles' velocity:
``flow.new_particle_velocity``), as a mixin of
:class:`~pfem2x.physics.flow.pfem2.LagrangianFlow` (its attributes: ``cloud_``,
``u``, ``u_hat``, ``phase``, ``dist``, ``dofmap``, ``cell_vol``, ...).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import particles as P
from pfem2x.compat import MPI
from pfem2x.physics.flow._kernels import particle_fraction_kernel
from pfem2x.physics.flow.interface import positive_fraction

__all__ = ["ParticleTransfers"]


class ParticleTransfers:
    """Transfers between the particles and the P1 mesh of the PFEM-2 flow frame."""

    cloud_: Any
    affine: bool
    mass_weighted: bool
    pic_fraction: float
    pic_fraction_light: float
    level_shift: float
    #: the first of two passes is running (:mod:`.passes`)
    _first_pass: bool = False

    def _update_phase_fields(self, velocity: bool = False) -> None:
        """Cell fractions → DG0 density and viscosity; P1 phase and ``phi`` (collective).

        ``velocity``: step 2's velocity projection first. The plain velocity, the
        phase and the level set ``dist`` are projected by one call
        (:func:`pfem2x.particles.project_fields`: one pass over the particles where it
        can, the same values); the affine or mass-weighted velocity before it
        (:meth:`_project_velocity`).
        """
        c = self.cloud_
        pr = self.problem
        (_, r1, m1, _) = pr.phases[0]
        specs = []
        if velocity and not (self.affine or self.mass_weighted):
            specs.append(("u", self.u_hat, self._plain_velocity_method()))
        elif velocity:
            self._project_velocity()
        phase = pr.two_phase and self._phase_projected()
        if phase:
            specs.append(("phase", self.phase, "average"))
        if pr.two_phase and self.dist is not None:
            # linear-exact fit: a flat layer's distance gives a flat zero iso-line
            specs.append(("dist", self.dist, "linear"))
        if specs:
            P.project_fields(c, specs, empty="neighbours")
        if phase:
            self.phi.x.array[:] = self.phase.x.array - 0.5
        if not pr.two_phase:
            self.frac[:] = 1.0
        else:
            if self.jump is not None and self.level_set_density:
                if self.conserve_volume:
                    self._conserve_volume()
                self.jump.update(self.dist.x.array)
                # the density's interface is the balanced force's: the cut-cell fraction
                self.frac[:] = positive_fraction(self.dist.x.array[self.dofmap[: self.n_owned]])
            else:
                if self.jump is not None:
                    self.jump.update(self.dist.x.array)
                self.frac[:] = self._particle_fraction()
            if self.capillary is not None:
                self._update_capillary()
        (_, r2, m2, _) = pr.phases[1] if pr.two_phase else pr.phases[0]
        f = self.frac
        self.rho.x.array[self._cell_dofs] = r2 + (r1 - r2) * f
        self.mu.x.array[self._cell_dofs] = m2 + (m1 - m2) * f
        self.rho.x.scatter_forward()
        self.mu.x.scatter_forward()

    def _particle_fraction(self) -> np.ndarray:
        """Fraction of each owned cell's particles with ``phase = 1`` (empty: the P1 phase)."""
        c = self.cloud_
        return particle_fraction_kernel(
            c.cells, c.field("phase"), self.n_owned, self.phase.x.array, self.dofmap
        )

    def _phase_projected(self) -> bool:
        """Whether this pass projects the P1 ``phase`` (``"average"``) and ``phi = phase - 1/2``.

        Output, tips and new particles read them, and the particles' cell density
        (``flow.density = "particles"``) in empty cells; so with the level set's
        density the first of two passes skips them (the second overwrites them).
        """
        return not (self._first_pass and self.level_set_density and self.jump is not None)

    def _conserve_volume(self) -> None:
        r"""Shift the level set ``dist`` so the heavy phase keeps its initial volume (collective).

        The area where the P1 ``dist`` is positive changes as the particles carry
        it: the P1 velocity is divergence-free only in the weak sense, and the
        linear fit moves its zero iso-line within cells (Rayleigh–Taylor 16 × 64 at
        Courant 8: 1.1 % in 5 steps; 100 × 400: 0.36 %). One constant :math:`s` is
        added to ``dist`` (the P1 field and every particle's), the root of
        :math:`V(s) = V_0` (``volume0``), :math:`V(s)` the area where
        :math:`d + s > 0` (cut-cell fractions), by the Illinois rule to
        :math:`10^{-12}` of the domain: the interface moves along its normal by
        about :math:`s/|\nabla d|` everywhere. :attr:`level_shift` is the last
        :math:`s`. Nothing is shifted before ``volume0`` is known (the start) or
        when no shift brings the volume back (no interface).
        """
        self.level_shift = 0.0
        if not self.volume0:
            return
        target = self.volume0[self.problem.phases[0][0]]
        arr = self.dist.x.array
        vals = arr[self.dofmap[: self.n_owned]]
        cv = self.cell_vol

        def excess(s: float) -> float:
            v = float(np.dot(positive_fraction(vals + s), cv))
            return float(self.comm.allreduce(v, op=MPI.SUM)) - target

        tol = 1e-12 * float(self.comm.allreduce(float(cv.sum()), op=MPI.SUM))
        a, fa = 0.0, excess(0.0)
        if abs(fa) <= tol:
            return
        b = -self.H if fa > 0.0 else self.H  # V grows with s
        fb = excess(b)
        while fa * fb > 0.0 and abs(b) < 1e3 * self.H:  # widen the bracket
            a, fa = b, fb
            b *= 2.0
            fb = excess(b)
        if fa * fb > 0.0:
            return
        for _ in range(100):  # Illinois (regula falsi, the stale end's value halved)
            x = b - fb * (b - a) / (fb - fa)
            fx = excess(x)
            if abs(fx) <= tol:
                b = x
                break
            if fx * fb < 0.0:
                a, fa = b, fb
            else:
                fa *= 0.5
            b, fb = x, fx
        self.level_shift = b
        arr += b
        self.cloud_.field("dist")[:] += b

    def _increment_particles(self) -> None:
        """Step 4: ``u_p += (u^{n+1} - u_hat)(x_p)``, the PIC blend, the affine part.

        Nothing in the first of two passes: the second starts again from the particles
        of the start of the step (:mod:`.passes`), so the first pass's are dropped.
        """
        if self._first_pass:
            return
        c = self.cloud_
        self.du.x.array[:] = self.u.x.array - self.u_hat.x.array
        P.add_increment(c, "u", self.du)
        a = self.pic_fraction
        al = self.pic_fraction_light
        alpha = None
        if a > 0.0 or al > 0.0:
            up = c.field("u")
            alpha = np.full(c.n, a)
            if al > 0.0:
                alpha[c.field("phase") < 0.5] = al
            up *= 1.0 - alpha[:, None]
            up += alpha[:, None] * P.evaluate(c, self.u)
        if self.affine:
            self._set_affine(alpha)

    def _set_affine(self, alpha: np.ndarray | None = None) -> None:
        """``C_p = grad u(x_p)`` of the mesh velocity (constant per P1 cell), ``flow.affine``."""
        c = self.cloud_
        g = self.gdim
        if alpha is None:  # no particle takes the mesh velocity: no affine part
            c.field2d("grad_u")[:] = 0.0
            return
        vals = np.asarray(self.u.x.array).reshape(-1, g)
        cells = c.cells
        cv = vals[self.dofmap[cells]]  # (n, nodes, gdim)
        inv = self.domain.table.inv_map[cells]  # (n, tdim, gdim)
        c.field2d("grad_u")[:] = np.einsum(
            "nia,nib->nab", cv[:, 1:, :] - cv[:, :1, :], inv
        ).reshape(-1, g * g)
        c.field2d("grad_u")[:] *= alpha[:, None]

    def _project_velocity(self) -> None:
        """Step 2 for ``u``: plain projection, or mass-weighted (``flow.mass_weighted``).

        A pass projects the plain velocity with the phase fields
        (:meth:`_update_phase_fields`), the others by this method.

        Mass-weighted: ``u_i = sum w_p rho_p u_p / sum w_p rho_p`` (``"average"``
        weights ``w_p = N_i(x_p)``; a linear fit of the step in ``rho`` could
        leave ``[rho_light, rho_heavy]``). At a node of the interface the heavy
        phase's velocity then dominates as its mass does in the lumped
        ``rho``-mass, instead of an equal share of the light phase's
        velocities, whose divergence the pressure step would otherwise correct
        by moving the light phase.
        """
        c = self.cloud_
        if self.affine:
            self._project_affine()
            return
        if not self.mass_weighted:
            meth = self._plain_velocity_method()
            P.project(c, "u", self.u_hat, method=meth, empty="neighbours")
            return
        g = self.gdim
        (_, r1, _, _), (_, r2, _, _) = self.problem.phases
        m = c.field2d("_mom")
        rho_p = r2 + (r1 - r2) * c.field("phase")
        m[:, :g] = rho_p[:, None] * c.field("u")
        m[:, g] = rho_p
        P.project(c, "_mom", self._mom_nodes, method="average", empty="neighbours")
        mn = self._mom_nodes
        ok = mn[:, g] > 0.0
        uh = self.u_hat.x.array.reshape(-1, g)
        uh[ok] = mn[ok, :g] / mn[ok, g:]

    def _plain_velocity_method(self) -> str:
        """``method.projection`` of the plain velocity projection (``"auto"`` resolved)."""
        meth = self.scene.method.projection
        if meth == "auto":  # (the average is biased on an outflow side's one-sided nodes)
            meth = "linear" if self.problem.outflow else "average"
        return meth

    def _project_affine(self) -> None:
        r"""Step 2, ``flow.affine``: :math:`u_i = \sum_p w_p (u_p + C_p(x_i - x_p)) / \sum_p w_p`.

        ``w_p = N_i(x_p)`` (times :math:`\rho_p` with ``flow.mass_weighted``). The sum
        splits into the particles' :math:`u_p - C_p x_p` and :math:`C_p`, both projected
        with the ``"average"`` weights: :math:`u_i = \overline{u - Cx}_i + \overline{C}_i x_i`.
        Exact for a linear velocity (``u_p``, ``C_p`` sampled from it), with the
        average's positive weights.
        """
        c = self.cloud_
        g = self.gdim
        C = c.field2d("grad_u").reshape(-1, g, g)
        w = c.field2d("_aff")
        if self.mass_weighted:
            (_, r1, _, _), (_, r2, _, _) = self.problem.phases
            rho_p = r2 + (r1 - r2) * c.field("phase")
        else:
            rho_p = np.ones(c.n)
        w[:, :g] = rho_p[:, None] * (c.field("u") - np.einsum("nab,nb->na", C, c.x[:, :g]))
        w[:, g : g + g * g] = rho_p[:, None] * C.reshape(-1, g * g)
        if self.mass_weighted:
            w[:, -1] = rho_p
        nodes = np.zeros((len(self.coords), w.shape[1]))
        if self.mass_weighted:
            nodes[:, -1] = 1.0
        P.project(c, "_aff", nodes, method="average", empty="neighbours")
        if self.mass_weighted:
            nodes /= np.where(nodes[:, -1:] > 0.0, nodes[:, -1:], 1.0)
        xi = self.coords[:, :g]
        uh = self.u_hat.x.array.reshape(-1, g)
        uh[:] = nodes[:, :g] + np.einsum(
            "nab,nb->na", nodes[:, g : g + g * g].reshape(-1, g, g), xi
        )

    def _rebalance(self) -> None:
        """Step 5: population control; the phase stays sharp."""
        c = self.cloud_
        meth = self.scene.method
        nmin, nmax = meth.min_particles_per_cell, meth.max_particles_per_cell
        if nmin > 0 or nmax > 0:
            fb = {"u": self.u}
            if self.problem.two_phase:
                fb["phase"] = self.phase
            if self.dist is not None:
                fb["dist"] = self.dist
            # flow.new_particle_velocity: "mesh" u_h(x), "mesh_deviation" + the cell's
            # mean u_p - u_h(x_p), "fit" the fit of the particles near
            mode = self.scene.flow.new_particle_velocity
            self.last_population = P.rebalance(
                c,
                nmin,
                nmax,
                seed=meth.seed + 7919 * (self.step_count + 1),
                fallback=fb,
                mesh_fields=None if mode == "fit" else {"u": self.u},
                mesh_deviation=mode == "mesh_deviation",
            )
            if self.problem.two_phase:
                ph = c.field("phase")
                ph[:] = ph > 0.5
