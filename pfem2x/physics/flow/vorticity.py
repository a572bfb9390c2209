r"""The viscous term of the pressure Poisson equation, in the rotational form.

For a divergence-free velocity with constant kinematic viscosity ν the viscous
acceleration is :math:`\nu\Delta u = -\nu\,\nabla\times\omega`,
:math:`\omega = \nabla\times u`. It needs one derivative of the vorticity, not two
of the velocity, so a P1 velocity gives it through a P1 vorticity: the lumped
projection of the cell-wise curl of ``u``. In the weak pressure Poisson equation,
tested with ``r``, the term is

.. math:: \int_\Omega \nabla r\cdot\nu\Delta u\,dx
          = -\int_\Omega \nu\,\nabla r\cdot(\nabla\times\omega_h)\,dx,

which for P1 ``r`` and ``ω_h`` is a boundary integral of the vorticity (the
curl of ``ω_h`` is divergence free): it is what makes the pressure of a
wall-bounded viscous flow (a channel's ``dp/dx = μ u''``) the Neumann data
``n·ν Δu`` of the consistent pressure (Orszag, Israeli & Deville 1986;
Karniadakis, Israeli & Orszag 1991, "rotational" pressure boundary condition).
The projection is exact for a vorticity linear in space (Poiseuille flow) on the
nodes inside the domain and first order on the boundary nodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem

__all__ = ["RotationalViscousTerm"]


class RotationalViscousTerm:
    """``ω_h`` (P1, lumped projection of ``curl u``) and the term ``-ν ∇r·curl ω_h``.

    Parameters
    ----------
    u:
        The P1 velocity (2 or 3 components).
    nu:
        The kinematic viscosity (a UFL expression, e.g. ``mu / rho``).
    """

    def __init__(self, u: Any, nu: Any):
        mesh = u.function_space.mesh
        gdim = mesh.geometry.dim
        self.W = compat.function_space(mesh, 1, None if gdim == 2 else (3,))
        self.omega = compat.dolfinx.fem.Function(self.W, name="vorticity")
        s = ufl.TestFunction(self.W)
        dx = ufl.dx(domain=mesh)
        self._L = compat.form(ufl.inner(ufl.curl(u), s) * dx)
        self._b = compat.create_vector(self._L)
        one = ufl.as_vector([1.0] * 3) if gdim == 3 else 1.0
        L_one = compat.form(ufl.inner(one, s) * dx)
        lumped = compat.create_vector(L_one)
        fem.assemble_vector(L_one, lumped)
        self._lumped = np.array(lumped.array_r)
        self.nu = nu

    def term(self, r: Any) -> Any:
        """``-ν ∇r·curl ω_h`` (integrand; ``r`` the pressure's test function)."""
        return -self.nu * ufl.dot(ufl.grad(r), ufl.curl(self.omega))

    def update(self) -> None:
        """``ω_h`` from the current velocity (collective)."""
        fem.assemble_vector(self._L, self._b)
        n = len(self._lumped)
        self.omega.x.array[:n] = self._b.array_r / self._lumped
        self.omega.x.scatter_forward()
