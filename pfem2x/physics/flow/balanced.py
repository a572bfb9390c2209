r"""Balanced-force gravity of two phases: a jump force in the pressure gradient's space.

For a sharp density :math:`\rho` and any function :math:`f` constant along
the interface normals with :math:`f = g\cdot x` on the interface :math:`\Gamma`
(:math:`f(x) = g\cdot x_\Gamma(x)`, :math:`x_\Gamma` the closest interface point),

.. math::
    \rho g = \nabla\big(\rho\,(g\cdot x - f)\big) + \rho\,\nabla f,

because :math:`(g\cdot x - f)\nabla\rho = 0` (:math:`\nabla\rho` lives on
:math:`\Gamma`). The first term is the gradient of the kinked hydrostatic
pressure of a locally flat interface; the second is gravity's component along
the interface (zero for a flat interface normal to :math:`g`). With
:math:`q = g\cdot x - f` (the height above the interface times :math:`|g|`),
the discrete force of both flow frames is

.. math::
    b_h = \rho_w\,g + \underbrace{\nabla I_h(\rho_h q_h) - \rho_w\nabla q_h}_{J_h},

- :math:`\rho_w`: the frame's own density (the weight of its pressure equation
  and mass matrix: smoothed level set, or the particles' cell fractions);
- :math:`\rho_h`: the P1 function of the nodal sharp density (phase 1 where
  the level set is :math:`\geq 0`);
- :math:`q_h`: P1, nodal :math:`q_i = g\cdot(x_i - x_{\Gamma,i})` with
  :math:`x_{\Gamma,i}` the closest point of the level set's zero iso-line, on
  the band :math:`B` of nodes within ``band`` of it and every node of a cell
  whose nodal densities differ; :math:`q_i = 0` elsewhere.

:math:`J_h` is the jump force: it vanishes in every cell where :math:`\rho_h`
and :math:`\rho_w` are one constant (there :math:`b_h = \rho g` exactly), so it
lives on the cells next to the interface. :math:`b_h` is a cell-wise
gradient of P1 functions times cell densities, the pressure gradient's form,
and :math:`b_h/\rho_w = g - \nabla q_h + \nabla I_h(\rho_h q_h)/\rho_w` stays of
the order of :math:`g` (a node on the interface has :math:`q_i = 0`).

Discrete equilibrium: if the interface is flat and normal to :math:`g`
(:math:`g\cdot x_{\Gamma,i} = c` on :math:`B`), then :math:`q_h = I_h(g\cdot x) - c`
is linear on every cell with all nodes in :math:`B`, so :math:`\nabla q_h = g`
there and :math:`b_h = \nabla I_h(\rho_h q_h)`; on every other cell the
densities are one constant and :math:`b_h = \rho g = \nabla I_h(\rho_h q_h)` too.
So :math:`b_h = \nabla\Phi_h` with :math:`\Phi_h = I_h(\rho_h(g\cdot x - c))`, the
nodal interpolant of the exact hydrostatic pressure, wherever the interface
lies inside the cells. A P1 pressure :math:`p_h = \Phi_h` + const makes
:math:`b_h - \nabla p_h` vanish pointwise, so every form built from it
(predictor, pressure right-hand side, velocity correction, particle source)
vanishes for any weight and quadrature: the fluid stays at rest to round-off
and solver tolerance.

A capillary force :math:`\sigma\kappa\nabla H` fits the same jump term: with
:math:`\kappa` constant it is :math:`\nabla I_h(\sigma\kappa H_h)`, balanced
by a pressure jump :math:`\sigma\kappa` (add :math:`\sigma\kappa_h H_h` to the
potential :math:`I_h(\rho_h q_h)`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.physics.flow._kernels import closest_points_kernel, mark_mixed_cells
from pfem2x.physics.flow.interface import InterfaceGeometry

__all__ = ["JumpForce", "closest_points"]


class JumpForce:
    """The balanced body force :math:`b_h = \rho_w g + \nabla I_h(\rho_h q_h) - \rho_w\nabla q_h`.

    Parameters
    ----------
    Q
        The P1 space (:math:`q_h` and :math:`I_h(\rho_h q_h)`).
    interface
        The mesh partition's :class:`~pfem2x.physics.flow.interface.InterfaceGeometry`.
    rho1, rho2
        Densities of phase 1 (level set :math:`\\geq 0`) and phase 2.
    gravity
        ``(gdim,)`` gravity vector.
    band
        Nodes within this distance of the interface get their :math:`q_i`
        (at least the nodes of the cells the nodal densities differ on).
    """

    def __init__(
        self,
        Q: Any,
        interface: InterfaceGeometry,
        rho1: float,
        rho2: float,
        gravity: np.ndarray,
        band: float,
    ):
        gdim = len(gravity)
        self.interface = interface
        self.rho1, self.rho2 = float(rho1), float(rho2)
        self.g = np.asarray(gravity, dtype=float)
        self.band = float(band)
        self._xy = interface.coords[:, :gdim]
        #: g.x at the nodes
        self._gx = self._xy @ self.g
        #: q_h (P1), the potential I_h(rho_h q_h) (P1), a work function (band marks)
        self.q = compat.dolfinx.fem.Function(Q, name="q")
        self.Pi = compat.dolfinx.fem.Function(Q, name="Pi")
        self._mark = compat.dolfinx.fem.Function(Q)

    def force(self, rho_w: Any, g: Any) -> Any:
        """The UFL force :math:`b_h` with the frame's density ``rho_w`` and gravity ``g``."""
        return rho_w * (g - ufl.grad(self.q)) + ufl.grad(self.Pi)

    def update(self, phi: np.ndarray) -> None:
        """Recompute :math:`q_h` and :math:`I_h(\rho_h q_h)` from nodal level-set values.

        ``phi`` holds owned and ghost values. Collective: the interface segments
        are gathered and the band marks are summed over the ranks sharing a node.
        """
        itf = self.interface
        h = phi >= 0.0
        rho = np.where(h, self.rho1, self.rho2)
        mark = self._mark.x.array
        mark[:] = 0.0
        mark_mixed_cells(phi, itf.dofmap, mark)  # the nodes of cells the densities differ on
        compat.scatter_reverse_add(self._mark.x)  # the owner learns of cells it lacks
        compat.scatter_forward(self._mark.x)
        near = (mark > 0.0) | (np.abs(phi) < self.band)
        segs = itf.gather(itf.segments(phi))
        q = np.zeros(len(phi))
        if len(segs) and near.any():
            q[near] = self._gx[near] - closest_points(self._xy[near], segs) @ self.g
        self.q.x.array[:] = q
        self.Pi.x.array[:] = rho * q


def closest_points(points: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """The closest point of the segments ``(m, 2, 2)`` to each point ``(n, 2)``: ``(n, 2)``.

    Compiled (:func:`~pfem2x.physics.flow._kernels.closest_points_kernel`): each point
    against the segments of the buckets around it, nearest first, not all of them.
    """
    pts = np.ascontiguousarray(points, dtype=np.float64)
    return closest_points_kernel(pts, np.ascontiguousarray(segs, dtype=np.float64))
