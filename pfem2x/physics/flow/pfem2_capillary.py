"""The surface-tension parts of the PFEM-2 flow frame (:class:`~.pfem2.LagrangianFlow`).

The capillary force (:mod:`pfem2x.physics.flow.capillary`) on the zero iso-line of the P1
level set ``dist`` (the linear-exact projection of the particles' signed distance), its
curvature fitted to the particles' own signed distances
(:func:`~pfem2x.physics.flow.curvature.distance_curvature`), which start as the distance to
the region's boundary sampled below the mesh size
(:func:`~pfem2x.physics.flow.curvature.region_distance`), are carried, and are re-distanced
within 3 cells of the interface after each update of the force (``flow.particle_redistance``,
:meth:`ParticleCapillary._update_capillary`): the distance to the circles the curvature was
fitted with, so the flow does not stretch them (the fit's guard then rejects them).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.physics.flow.capillary import CapillaryForce, capillary_increment, region_distance

__all__ = ["ParticleCapillary"]


class ParticleCapillary:
    """Surface tension in the PFEM-2 frame (a part of :class:`~.pfem2.LagrangianFlow`)."""

    capillary: CapillaryForce | None
    #: the particles' ``dist`` within this of the interface is re-distanced each update
    #: (:meth:`_update_capillary`; 0: never)
    redistance_band: float = 0.0
    dist: Any
    cloud_: Any

    def _init_capillary(self) -> None:
        """``effects.surface_tension``: the capillary force on the zero iso-line of ``dist``."""
        pr = self.problem
        if not (pr.two_phase and pr.surface_tension > 0.0):
            return
        if self.dist is None:
            self.dist = compat.dolfinx.fem.Function(self.Q, name="dist")
        # band: every cell a fraction between 0 and 1 may sit in has its nodes in it;
        # the curvature: fitted to the particles' signed distances while they are ones
        # (re-distanced each step, their lambda departs from 1 by the fit's misfit of the
        # shape, not by stretch: the rising bubble at h = 1/40 kept its circularity error
        # at 0.73 % with 0.1, 1.16 % with 0.05, which left 10-16 % of its segments late on
        # the end-point fit)
        redistance = bool(self.scene.flow.particle_redistance)
        self.capillary = CapillaryForce(
            self.Q,
            self.interface,
            pr.surface_tension,
            2.0 * self.H,
            self.H,
            samples=lambda: (self.cloud_.x, self.cloud_.field("dist")),
            stretch_tolerance=0.1 if redistance else 0.05,
            damping=self.scene.flow.capillary_damping,
            extrapolate=True,
        )
        if redistance:
            self.redistance_band = 3.0 * self.H

    def _update_capillary(self) -> None:
        r"""The capillary force of the P1 ``dist``, then the particles' ``dist`` re-distanced.

        Within :attr:`redistance_band` of the interface (the particles' own ``|dist|``) each
        particle gets the distance to the interface the curvature was just fitted on
        (:meth:`.CapillaryForce.redistance_samples`: the fitted circles), its sign kept:
        the flow stretches the carried ``dist`` (the rising bubble's :math:`\lambda`
        reached 6 by t = 2 at h = 1/40, and beyond :math:`|\lambda - 1| = 0.05` the
        distance fit is not used), re-distanced each step it stays a distance. Particles
        farther away keep theirs. ``redistance_band = 0``: not re-distanced.
        """
        self.capillary.update(self.dist.x.array, self.cell_vol)
        if self.redistance_band > 0.0:
            c = self.cloud_
            self.capillary.redistance_samples(c.x, c.field("dist"), self.redistance_band)

    def _seed_capillary_dist(self, region: Any) -> None:
        """With surface tension: the particles' ``dist``, the region's distance below ``h``.

        (Interpolated from the P1 ``dist``, the distance to the mesh's chords, the curvature
        fit at h = 1/40 scattered by 6e-3 of 1/R on a static drop.)
        """
        if self.capillary is not None:
            x = self.cloud_.x
            self.cloud_.field("dist")[:] = region_distance(self.interface, region, x)

    def _capillary_increment(self, dt: float) -> None:
        """``flow.capillary_increment`` (:func:`.capillary.capillary_increment`; lumped mass)."""
        proj = self.projection

        def mass(x: Any, y: Any) -> None:
            y.pointwiseMult(x, proj.b_mass)
            y.scale(1.0 / dt)

        def project() -> None:
            proj.solve_increment()
            proj.correct(self.u, self.p, dt, mass_ready=True)
            self._update_force()

        capillary_increment(self.u, self.u_star, self.m_solver, mass, project)

    def _phase_weight(self) -> Any:
        """The frame's phase-1 weight: the DG0 density's cell fractions (UFL)."""
        (_, r1, _, _), (_, r2, _, _) = self.problem.phases
        return (self.rho - r2) / (r1 - r2)

    def interface_function(self) -> np.ndarray:
        """The projected signed distance ``dist`` (surface tension, gravity), else ``phi``."""
        return self.dist.x.array if self.dist is not None else self.phi.x.array
