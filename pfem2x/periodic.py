r"""Periodic P1 constraints for mesh solves (DOLFINx has no periodic boundary conditions).

Every P1 dof on the *max* face of a periodic axis is identified with its
partner on the *min* face (corners and edges are chased through all periodic
axes, so a corner maps to the min-min-... corner). With the restriction
matrix :math:`P` (full space → reduced space, one unit entry per row) a system
:math:`A x = b` on the full space becomes

.. math:: P^T A P\, x_r = P^T b, \qquad x = P x_r .

The construction is parallel: owned dofs are numbered globally in the
reduced space, and the owned min-face dofs (the partners) are gathered on all
ranks so that every max-face dof can find its partner's reduced index,
whichever rank owns it. The gathered set is a codimension-one slice of the
dofs, so the memory it needs is small next to the mesh.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x.compat import MPI, PETSc

__all__ = ["PeriodicConstraint", "PeriodicError"]


class PeriodicError(ValueError):
    """The mesh is not periodic-conforming (a max-face dof has no min-face partner)."""


class PeriodicConstraint:
    """Identify the P1 dofs of opposite faces of a box along its periodic axes.

    Parameters
    ----------
    V:
        A scalar P1 function space.
    bounds:
        ``(2, gdim)`` global bounding box of the mesh.
    periodic:
        One bool per axis.
    h:
        A length below the mesh size (the shortest edge); sets the tolerances.

    Attributes
    ----------
    P:
        The PETSc restriction matrix, rows: full space (owned dofs), columns:
        reduced space.
    num_slaves:
        Global number of identified (removed) dofs.
    """

    def __init__(self, V: Any, bounds: Any, periodic: Any, h: float):
        comm: MPI.Comm = V.mesh.comm
        self.comm = comm
        imap = V.dofmap.index_map
        n_own = int(imap.size_local)
        gdim = V.mesh.geometry.dim
        x = np.asarray(V.tabulate_dof_coordinates())[:n_own, :gdim]
        bounds = np.asarray(bounds, dtype=float).reshape(2, -1)
        lo, hi = bounds[0, :gdim], bounds[1, :gdim]
        tol = 1e-6 * h
        canon = x.copy()
        slave = np.zeros(n_own, dtype=bool)
        on_min = np.zeros(n_own, dtype=bool)
        for ax, per in enumerate(periodic):
            if not per:
                continue
            at_hi = np.abs(x[:, ax] - hi[ax]) < tol
            canon[at_hi, ax] = lo[ax]
            slave |= at_hi
            on_min |= np.abs(x[:, ax] - lo[ax]) < tol
        master = ~slave
        n_red = int(master.sum())
        start = comm.exscan(n_red, op=MPI.SUM) if comm.size > 1 else 0
        start = int(start or 0)
        red = np.full(n_own, -1, dtype=np.int64)
        red[master] = start + np.arange(n_red, dtype=np.int64)

        # partners: owned master dofs on a min face, gathered everywhere
        quantum = 1e-3 * h
        cand = master & on_min
        cand_keys = np.round((x[cand] - lo) / quantum).astype(np.int64)
        cand_red = red[cand]
        if comm.size > 1:
            cand_keys = np.concatenate(comm.allgather(cand_keys)).reshape(-1, gdim)
            cand_red = np.concatenate(comm.allgather(cand_red))
        self.num_slaves = int(comm.allreduce(int(slave.sum()), op=MPI.SUM))
        s_keys = np.round((canon[slave] - lo) / quantum).astype(np.int64)
        bad = 0
        if len(s_keys):
            allk = np.concatenate([cand_keys, s_keys], axis=0)
            _, inv = np.unique(allk, axis=0, return_inverse=True)
            inv = np.asarray(inv).ravel()
            m = len(cand_keys)
            lookup = np.full(int(inv.max()) + 1, -1, dtype=np.int64)
            lookup[inv[:m]] = cand_red
            found = lookup[inv[m:]]
            bad = int((found < 0).sum())
            red[slave] = found
        bad = comm.allreduce(bad, op=MPI.SUM)
        if bad:
            raise PeriodicError(
                f"mesh.periodic: {bad} dofs on a max face have no partner on the opposite "
                "face (the mesh is not periodic-conforming)"
            )
        n_glob = int(imap.size_global)
        nr_glob = int(comm.allreduce(n_red, op=MPI.SUM))
        self.num_reduced = nr_glob
        indptr = np.arange(n_own + 1, dtype=PETSc.IntType)
        indices = red.astype(PETSc.IntType)
        data = np.ones(n_own, dtype=PETSc.ScalarType)
        self.P = PETSc.Mat().createAIJ(
            size=((n_own, n_glob), (n_red, nr_glob)), csr=(indptr, indices, data), comm=comm
        )
        self.P.assemble()
        self.xr = self.P.createVecRight()
        self.br = self.P.createVecRight()

    def reduce_matrix(self, A: Any, result: Any = None) -> Any:
        """:math:`P^T A P`, into ``result`` when given (same pattern), else a new matrix."""
        if result is None:
            return A.PtAP(self.P)
        A.PtAP(self.P, result=result)
        return result

    def reduce_vector(self, b: Any) -> Any:
        """:math:`P^T b` into the internal reduced right-hand side (returned)."""
        self.P.multTranspose(b, self.br)
        return self.br

    def restrict(self, x: Any) -> Any:
        """A reduced vector holding the master values of the full vector ``x``.

        (Used as an initial guess: each reduced dof takes the value of its
        owning full-space dof.)
        """
        # P^T x sums the copies; divide by the multiplicity
        ones = self.P.createVecLeft()
        ones.set(1.0)
        mult = self.P.createVecRight()
        self.P.multTranspose(ones, mult)
        self.P.multTranspose(x, self.xr)
        self.xr.pointwiseDivide(self.xr, mult)
        ones.destroy()
        mult.destroy()
        return self.xr

    def expand(self, xr: Any, x: Any) -> None:
        """``x = P xr`` on the owned entries of ``x`` (call ``scatter_forward`` after)."""
        self.P.mult(xr, x)

    def destroy(self) -> None:
        """Free the PETSc objects."""
        for obj in (self.P, self.xr, self.br):
            if obj is not None:
                obj.destroy()
