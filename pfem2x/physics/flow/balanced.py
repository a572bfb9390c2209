r"""Balanced-force gravity of two phases: a jump force in the pressure gradient's space.

With a sharp density :math:`\rho = \rho_2 + (\rho_1 - \rho_2) H` (:math:`H` the
indicator of phase 1) the body force splits, for any :math:`\rho`, into

.. math::
    \rho g = \nabla(\rho\, g\cdot x) - (g\cdot x)\nabla\rho
           = \nabla(\rho\, g\cdot x) - (\rho_1 - \rho_2)(g\cdot x_\Gamma)\nabla H,

since :math:`\nabla H` is concentrated on the interface, where
:math:`x = x_\Gamma`. The discrete force of both flow frames is

.. math::
    b_h = \nabla\Psi_h + s_K\,\nabla H_h, \qquad
    \Psi_h = I_h(\rho_h\, g\cdot x), \quad
    s_K = -(\rho_1 - \rho_2)\, g\cdot x_{\Gamma,K},

with :math:`H_h` the P1 function of the nodal indicator (1 where the level
set is :math:`\geq 0`), :math:`\rho_h = \rho_2 + (\rho_1-\rho_2)H_h` and
:math:`x_{\Gamma,K}` the midpoint of the level set's zero iso-line in cell
:math:`K` (:math:`s_K = 0` in the cells it does not cross, where
:math:`\nabla H_h = 0`). :math:`b_h` is cell-wise constant, in the same space
as the gradient of the P1 pressure: in a cell with all nodes in one phase it
is exactly :math:`\rho g`; the rest is a jump force :math:`s_K\nabla H_h` on
the cells the interface crosses.

Discrete equilibrium: if :math:`g\cdot x_{\Gamma,K} = c` in every cut cell (a
flat interface normal to :math:`g`, wherever it lies inside the cells), then
:math:`b_h = \nabla\Phi_h` with the P1 function
:math:`\Phi_h = I_h(\rho_h\,g\cdot x) - (\rho_1-\rho_2)\,c\,H_h`, which is the
nodal interpolant of the exact hydrostatic pressure. A P1 pressure
:math:`p_h = \Phi_h` + const makes :math:`b_h - \nabla p_h` vanish pointwise,
so every form built from it (predictor, pressure right-hand side, velocity
correction, particle source) vanishes for any weight (:math:`\rho^{-1}`
smoothed or cell-wise) and any quadrature: the fluid stays at rest to
round-off and solver tolerance.

A capillary force :math:`\sigma\kappa\nabla H` fits the same term: add
:math:`\sigma\kappa_K` to :math:`s_K` (balanced by a pressure jump
:math:`\sigma\kappa` when :math:`\kappa_K` is constant on the interface).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat
from pfem2x.physics.flow.interface import _EDGES

__all__ = ["JumpForce"]


class JumpForce:
    """The balanced body force :math:`b_h = \\nabla\\Psi_h + s_K\\nabla H_h` of two phases.

    Parameters
    ----------
    Q
        The P1 space (:math:`H_h`, :math:`\\Psi_h`).
    coords
        ``(nodes, 3)`` P1 dof coordinates (owned and ghost).
    dofmap
        ``(cells, 3)`` P1 dofs of every local cell.
    n_owned
        Number of owned cells.
    rho1, rho2
        Densities of phase 1 (level set :math:`\\geq 0`) and phase 2.
    gravity
        ``(gdim,)`` gravity vector.
    """

    def __init__(
        self,
        Q: Any,
        coords: np.ndarray,
        dofmap: np.ndarray,
        n_owned: int,
        rho1: float,
        rho2: float,
        gravity: np.ndarray,
    ):
        mesh = Q.mesh
        gdim = len(gravity)
        self.rho1, self.rho2 = float(rho1), float(rho2)
        self.g = np.asarray(gravity, dtype=float)
        self.dofmap = dofmap
        self.n_owned = n_owned
        self.cell_xy = coords[dofmap[:n_owned]][:, :, :gdim]
        #: g.x at the nodes
        self._gx = coords[:, :gdim] @ self.g
        self.W0 = compat.function_space(mesh, 0, family="DG")
        self._cell_dofs = compat.dofmap_array(self.W0)[:n_owned, 0]
        #: the nodal indicator H_h, the potential Psi_h = I_h(rho_h g.x), the jump strength s_K
        self.H = compat.dolfinx.fem.Function(Q, name="H")
        self.Psi = compat.dolfinx.fem.Function(Q, name="Psi")
        self.s = compat.dolfinx.fem.Function(self.W0, name="s")
        #: the force b_h (UFL, cell-wise constant)
        self.force = ufl.grad(self.Psi) + self.s * ufl.grad(self.H)

    def update(self, phi: np.ndarray) -> None:
        """Recompute :math:`H_h, \\Psi_h, s_K` from nodal level-set values (owned and ghost).

        Every rank computes its nodal values from its own (ghost-updated) ``phi``,
        so no communication is needed for ``H`` and ``Psi``; ``s`` of ghost cells
        is updated by a forward scatter (collective).
        """
        h = (phi >= 0.0).astype(float)
        self.H.x.array[:] = h
        self.Psi.x.array[:] = (self.rho2 + (self.rho1 - self.rho2) * h) * self._gx
        self.s.x.array[:] = 0.0
        vals = phi[self.dofmap[: self.n_owned]]
        pos = vals >= 0.0
        cut = pos.any(axis=1) & ~pos.all(axis=1)
        v, x, p = vals[cut], self.cell_xy[cut], pos[cut]
        # midpoint of the zero iso-line: the mean of its two edge crossings
        mid = np.zeros((len(v), x.shape[2]))
        for i, j in _EDGES:
            c = p[:, i] != p[:, j]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(c, v[:, i] / (v[:, i] - v[:, j]), 0.0)
            mid += np.where(c[:, None], x[:, i] + t[:, None] * (x[:, j] - x[:, i]), 0.0)
        mid *= 0.5
        self.s.x.array[self._cell_dofs[cut]] = -(self.rho1 - self.rho2) * (mid @ self.g)
        self.s.x.scatter_forward()
