r"""The PFEM-2 frame's per-pass right-hand sides from cell-wise constants.

With the density constant in each cell (the particles' phase fractions, a DG0
function) and P1 fields, two vectors that the Lagrangian flow frame assembles in
every pass are sums over the cells of one constant per cell times
:math:`\int_c\lambda_i = |c|/(d+1)` or :math:`\int_c\nabla\lambda_i = |c|\nabla\lambda_i`:

- the particles' source load :math:`\int(b_h - \nabla p)\cdot w`, the balanced body
  force :math:`b_h = \rho_c(g - \nabla q_h) + \nabla\Pi_h`
  (:class:`~pfem2x.physics.flow.balanced.JumpForce`; :math:`\rho_c g` without it, 0
  without gravity);
- the consistent pressure's right-hand side
  :math:`\int(\nabla u:\nabla u^T)\,r + \rho_c^{-1} b_h\cdot\nabla r`.

:class:`CellLoads` computes them by one pass over the owned cells (numba,
:func:`~pfem2x.physics.flow._load_kernels.force_load_kernel` and
:func:`~pfem2x.physics.flow._load_kernels.pressure_load_kernel`) and adds the ghost rows
to their owners as DOLFINx's assembly does: the same vectors as the forms' to
round-off (the sums are taken in another order), without packing the forms'
coefficients and running their generated kernels.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import cellwise, compat, fem
from pfem2x.compat import PETSc
from pfem2x.mesh import basis_gradients, geometry_table
from pfem2x.physics.flow._load_kernels import force_load_kernel, pressure_load_kernel

__all__ = ["CellLoads"]


class CellLoads:
    """The source load and the consistent pressure's right-hand side, cell by cell.

    Parameters
    ----------
    V, Q
        The P1 velocity (``gdim`` components) and pressure spaces.
    gravity
        ``(gdim,)`` gravity (zeros without it).
    jump
        The balanced force's :class:`~pfem2x.physics.flow.balanced.JumpForce` (its
        ``q`` and ``Pi``), or ``None``: :math:`b_h = \\rho_c g`.
    """

    def __init__(self, V: Any, Q: Any, gravity: np.ndarray, jump: Any = None):
        table = geometry_table(V.mesh)
        n = table.num_cells_owned
        self._grads = np.ascontiguousarray(basis_gradients(table))
        self._vol = np.ascontiguousarray(table.volume[:n], dtype=np.float64)
        self._qdofs = np.ascontiguousarray(compat.dofmap_array(Q)[:n])
        self._vdofs = np.ascontiguousarray(compat.dofmap_array(V)[:n])
        self._g = np.ascontiguousarray(gravity, dtype=np.float64)
        self._jump = jump
        self._zero = np.zeros(cellwise.local_size(Q))  # q = Pi = 0 without the jump force

    def _q_pi(self) -> tuple[np.ndarray, np.ndarray]:
        if self._jump is None:
            return self._zero, self._zero
        return self._jump.q.x.array, self._jump.Pi.x.array

    @staticmethod
    def _finish(b: Any) -> None:
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)

    def force(self, rho: np.ndarray, p: Any, b: Any) -> None:
        r""":math:`\int(b_h - \nabla p)\cdot w` into ``b`` (collective).

        ``rho``: the owned cells' densities; ``p`` the P1 pressure (a Function).
        """
        fem.COUNTERS["vector_assemblies"] += 1
        q, pi = self._q_pi()
        s = pi - p.x.array
        with b.localForm() as loc:
            loc.set(0.0)
            force_load_kernel(
                self._grads, self._vol, self._qdofs, self._vdofs, rho, self._g, q, s, loc.array
            )
        self._finish(b)

    def pressure(self, rho: np.ndarray, u: Any, b: Any) -> None:
        r""":math:`\int(\nabla u:\nabla u^T)\,r + \rho_c^{-1}b_h\cdot\nabla r` into ``b``
        (collective); ``u`` the P1 velocity (a Function)."""
        fem.COUNTERS["vector_assemblies"] += 1
        q, pi = self._q_pi()
        with b.localForm() as loc:
            loc.set(0.0)
            pressure_load_kernel(
                self._grads, self._vol, self._qdofs, self._vdofs, rho, self._g, q, pi,
                u.x.array, loc.array,
            )  # fmt: skip
        self._finish(b)
