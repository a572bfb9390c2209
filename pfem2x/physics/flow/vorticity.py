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
The lumped projection is exact for a vorticity linear in space (Poiseuille flow)
on the nodes inside the domain, but only first order on the boundary nodes, whose
cells all lie on one side (a wall node gets the vorticity half a cell in). Those
take the least-squares linear fit of the interior nodes within two edges instead,
exact for a linear vorticity (:func:`boundary_fit`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import ufl

from pfem2x import compat, fem

__all__ = ["RotationalViscousTerm", "boundary_fit"]


class RotationalViscousTerm:
    """``ω_h`` (P1, lumped projection of ``curl u``) and the term ``-ν ∇r·curl ω_h``.

    Parameters
    ----------
    u:
        The P1 velocity (2 or 3 components).
    nu:
        The kinematic viscosity (a UFL expression, e.g. ``mu / rho``).
    table:
        The mesh's :class:`~pfem2x.mesh.GeometryTable` (its boundary facets, for
        :func:`boundary_fit`).
    """

    def __init__(self, u: Any, nu: Any, table: Any):
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
        self._fit = boundary_fit(self.W, table)
        self._fitted_nodes = np.unique(self._fit[0])

    def term(self, r: Any) -> Any:
        """``-ν ∇r·curl ω_h`` (integrand; ``r`` the pressure's test function)."""
        return -self.nu * ufl.dot(ufl.grad(r), ufl.curl(self.omega))

    def update(self) -> None:
        """``ω_h`` from the current velocity (collective)."""
        fem.assemble_vector(self._L, self._b)
        n = len(self._lumped)
        self.omega.x.array[:n] = self._b.array_r / self._lumped
        self.omega.x.scatter_forward()
        rows, cols, coef = self._fit
        if len(rows):
            bs = self.W.dofmap.index_map_bs
            w = self.omega.x.array.reshape(-1, bs)
            fitted = np.zeros((len(w), bs))
            for k in range(bs):
                fitted[:, k] = np.bincount(rows, coef * w[cols, k], minlength=len(w))
            w[self._fitted_nodes] = fitted[self._fitted_nodes]
        self.omega.x.scatter_forward()


def boundary_fit(W: Any, table: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weights of the linear least-squares fit at the owned boundary nodes of P1 ``W``.

    For each owned node on the domain boundary: the value at the node of the linear
    function fitted to the values of the interior nodes within two edges of it
    (``value_b = sum coef * value[col]`` over its entries). Nodes whose interior
    neighbours do not determine a linear function keep their own value (no entries).

    Parameters
    ----------
    W:
        A P1 space (scalar or blocked).
    table:
        The mesh's :class:`~pfem2x.mesh.GeometryTable` (which cell facets are on
        the boundary).

    Returns
    -------
    rows, cols, coef:
        Boundary node, interior node and weight of each entry (local indices).
    """
    dofs = compat.dofmap_array(W)[: table.num_cells]
    imap = W.dofmap.index_map
    n_loc = imap.size_local + imap.num_ghosts
    gdim = table.gdim
    x = W.tabulate_dof_coordinates()[:n_loc, :gdim]
    # boundary nodes: the nodes of boundary facets (summed over the ranks)
    flag = compat.la_vector(imap)
    fa = np.asarray(flag.array)
    fa[:] = 0.0
    nv = dofs.shape[1]
    for i in range(nv):  # (cell-local vertex loop: tdim + 1 passes)
        on = table.facet_on_boundary[:, i]
        for j in range(nv):
            if j != i:
                fa[dofs[on, j]] = 1.0
    compat.scatter_reverse_add(flag)
    compat.scatter_forward(flag)
    bnd = fa > 0.0
    # node pairs sharing a cell (the first ring), sorted by the first node
    a = np.repeat(dofs, nv, axis=1).ravel()
    b = np.tile(dofs, (1, nv)).ravel()
    pairs = np.unique(np.stack([a, b], axis=1), axis=0)
    start = np.searchsorted(pairs[:, 0], np.arange(n_loc + 1))
    # the second ring of each owned boundary node: neighbours of its neighbours
    owned_b = np.flatnonzero(bnd[: imap.size_local])
    r1 = pairs[np.isin(pairs[:, 0], owned_b)]
    cnt = start[r1[:, 1] + 1] - start[r1[:, 1]]
    rb = np.repeat(r1[:, 0], cnt)
    idx = np.repeat(start[r1[:, 1]] - np.cumsum(cnt) + cnt, cnt) + np.arange(cnt.sum())
    r2 = np.unique(np.stack([rb, pairs[idx, 1]], axis=1), axis=0)
    r2 = r2[~bnd[r2[:, 1]]]
    # the fit's normal equations per boundary node, basis (1, x - x_b)
    phi = np.concatenate([np.ones((len(r2), 1)), x[r2[:, 1]] - x[r2[:, 0]]], axis=1)
    M = np.zeros((n_loc, gdim + 1, gdim + 1))
    np.add.at(M, r2[:, 0], phi[:, :, None] * phi[:, None, :])
    Mo = M[owned_b]
    ok = np.abs(np.linalg.det(Mo)) > 1e-10 * np.einsum("nii->n", Mo) ** (gdim + 1)
    if not ok.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    # the value at x_b is e0 . M^-1 sum(phi value): per node the first row of M^-1 (M symmetric)
    e0 = np.zeros((int(ok.sum()), gdim + 1, 1))
    e0[:, 0] = 1.0
    row0 = np.zeros((n_loc, gdim + 1))
    row0[owned_b[ok]] = np.linalg.solve(Mo[ok], e0)[:, :, 0]
    keep = np.zeros(n_loc, dtype=bool)
    keep[owned_b[ok]] = True
    keep = keep[r2[:, 0]]
    coef = np.einsum("ni,ni->n", row0[r2[keep, 0]], phi[keep])
    return r2[keep, 0], r2[keep, 1], coef
