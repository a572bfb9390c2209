r"""P1 operators linear in a cellwise-constant coefficient, re-assembled as one sparse product.

A bilinear form :math:`\int k\,B(q, r)` on affine simplices, with :math:`k` constant in
each cell (a DG0 density) and :math:`B` of P1 functions, is
:math:`A(k) = \sum_c k_c E_c`: the element matrices :math:`E_c` of :math:`k = 1` do not
change while :math:`k` does. :class:`CellwiseForm` computes them once, with the map from
every element entry to its place in the matrix (a sparse matrix :math:`S` from the
owned cells' coefficients to the rows of the assembled operator, local rows and ghost
rows both), and re-assembles by :math:`S k` and one insertion into the PETSc matrix
that DOLFINx created for the same form (its layout and local-to-global maps; the
ghost rows' values go to their owners in PETSc's assembly, as in DOLFINx's own
assembler). On one process the form adopts DOLFINx's first assembly as a matrix of
its own over the value array that :math:`S k` writes (:meth:`CellwiseForm.adopt`),
and a re-assembly is that product alone. The same for a linear form into a ghosted
vector.

The element tensors of the operators the flow frames re-assemble every pass
(:func:`p1_laplacian`, :func:`p1_gradient`, :func:`p1_lumped_mass`) are exact for
P1 on affine cells, so a re-assembly equals DOLFINx's to round-off
(``tests/test_cellwise.py`` compares both, serially and on 2 ranks).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import fem
from pfem2x.compat import PETSc
from pfem2x.mesh import basis_gradients

__all__ = ["CellwiseForm", "p1_gradient", "p1_laplacian", "p1_lumped_mass"]


def p1_laplacian(table: Any, dofs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r""":math:`\int \nabla q\cdot\nabla r` per owned cell: element matrices, rows, columns.

    Parameters
    ----------
    table
        The mesh's :class:`pfem2x.mesh.GeometryTable`.
    dofs
        The scalar P1 space's cell → dof table (:func:`pfem2x.compat.dofmap_array`).
    """
    n = table.num_cells_owned
    grad = basis_gradients(table)
    vol = np.asarray(table.volume[:n])
    E = vol[:, None, None] * np.matmul(grad, np.transpose(grad, (0, 2, 1)))
    d = np.ascontiguousarray(dofs[:n])
    return E, d, d


def p1_gradient(
    table: Any, vdofs: np.ndarray, qdofs: np.ndarray, bs: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r""":math:`\int \nabla q\cdot w` (:math:`w` a P1 vector test function): element matrices.

    Rows are the vector space's unrolled dofs (``bs * dof + component``), columns the
    scalar space's dofs. :math:`\int_c \lambda_i = |c|/(d+1)` and
    :math:`\nabla q` is constant in the cell.
    """
    n = table.num_cells_owned
    grad = basis_gradients(table)  # (n, j, comp)
    nv = grad.shape[1]
    vol = np.asarray(table.volume[:n]) / nv
    # E[c, (i, comp), j] = |c| / (d + 1) * d(lambda_j)/dx_comp
    E = np.broadcast_to(
        vol[:, None, None, None] * np.transpose(grad, (0, 2, 1))[:, None, :, :],
        (n, nv, bs, nv),
    ).reshape(n, nv * bs, nv)
    rows = (bs * vdofs[:n, :, None] + np.arange(bs)[None, None, :]).reshape(n, nv * bs)
    return np.ascontiguousarray(E), rows, np.ascontiguousarray(qdofs[:n])


def p1_lumped_mass(table: Any, vdofs: np.ndarray, bs: int) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`\int w\cdot(1, \dots, 1)` per owned cell: element vectors and their rows."""
    n = table.num_cells_owned
    nv = vdofs.shape[1]
    vol = np.asarray(table.volume[:n]) / nv
    E = np.repeat(vol[:, None], nv * bs, axis=1)
    rows = (bs * vdofs[:n, :, None] + np.arange(bs)[None, None, :]).reshape(n, nv * bs)
    return E, rows


class CellwiseForm:
    r"""Re-assemble :math:`\sum_c k_c E_c` from the owned cells' coefficients :math:`k`.

    Parameters
    ----------
    E
        ``(n_owned, nr, nc)`` element matrices (``(n_owned, nr)``: element vectors) of
        :math:`k = 1`.
    rows, cols
        ``(n_owned, nr)`` and ``(n_owned, nc)`` local unrolled row and column indices
        (owned and ghost), as the PETSc matrix's local-to-global maps number them;
        ``cols`` is ``None`` for a vector.
    n_rows, n_cols
        Local unrolled rows and columns (owned + ghosts).
    """

    def __init__(
        self,
        E: np.ndarray,
        rows: np.ndarray,
        cols: np.ndarray | None,
        n_rows: int,
        n_cols: int = 1,
    ):
        n, nr = rows.shape
        E = E.reshape(n, nr, -1)
        r = rows.astype(np.int64)[:, :, None] * n_cols
        key = (r if cols is None else r + cols[:, None, :]).reshape(-1)  # (n, nr, nc) entries
        order = np.argsort(key, kind="stable")
        keys = key[order]
        new = np.ones(len(keys), dtype=bool)
        np.not_equal(keys[1:], keys[:-1], out=new[1:])
        first = np.flatnonzero(new)
        unique = keys[first]
        unique_rows = unique // n_cols
        #: the structure of the re-assembled rows (local indices, CSR)
        self.indptr = np.searchsorted(unique_rows, np.arange(n_rows + 1)).astype(PETSc.IntType)
        self.indices = (unique - unique_rows * n_cols).astype(PETSc.IntType)
        #: the row of each entry (a vector's entries: one per row that an owned cell touches)
        self._entry_rows = unique_rows
        self.n_rows = n_rows
        # S: the structure's entries from the cells' coefficients, (n_entries, n_owned);
        # PETSc uses these arrays in place (kept here): each row's cells ascend (stable sort)
        self._csr = (
            np.append(first, len(keys)).astype(PETSc.IntType),
            (order // E[0].size).astype(PETSc.IntType),  # the cell of each entry
            np.ascontiguousarray(E.ravel()[order], dtype=PETSc.ScalarType),
        )
        self._S = PETSc.Mat().createAIJWithArrays((len(unique), n), self._csr, comm=PETSc.COMM_SELF)
        self._k = PETSc.Vec().createSeq(n, comm=PETSc.COMM_SELF)
        self._values = PETSc.Vec().createSeq(len(unique), comm=PETSc.COMM_SELF)
        #: one process: the matrix over the value array :attr:`_own_values` (see adopt)
        self._own: Any = None
        self._own_values: Any = None

    def _k_from(self, k: np.ndarray) -> Any:
        self._k.array[:] = k
        return self._k

    def _products(self, k: np.ndarray) -> np.ndarray:
        self._S.mult(self._k_from(k), self._values)
        return self._values.array_r

    def adopt(self, A: Any) -> Any:
        """On one process, a matrix of this form's own with ``A``'s values; else ``A``.

        ``A`` is DOLFINx's assembled matrix of the form. When it has this form's rows,
        columns and entries (one process), the returned matrix holds a copy of its values
        in the array that :meth:`matrix` then writes: a re-assembly is the product alone,
        without an insertion. Adopt the matrix at its first assembly, so that a solver
        sees one matrix object for the whole run (a preconditioner that re-uses its
        set-up for a re-assembled matrix, as GAMG's interpolation, behaves as with
        DOLFINx's). Under MPI, or for another structure, ``A`` itself is returned and
        :meth:`matrix` inserts into it.
        """
        if A.getComm().getSize() > 1:
            return A
        indptr, indices, values = A.getValuesCSR()
        if not (np.array_equal(indptr, self.indptr) and np.array_equal(indices, self.indices)):
            return A
        values = np.array(values, dtype=PETSc.ScalarType)
        self._own = PETSc.Mat().createAIJWithArrays(
            A.getSizes(), (self.indptr, self.indices, values), comm=PETSc.COMM_SELF
        )
        self._own_values = PETSc.Vec().createWithArray(values, comm=PETSc.COMM_SELF)
        return self._own

    def matrix(self, k: np.ndarray, A: Any) -> Any:
        """``A = sum_c k_c E_c`` (collective); ``A``: DOLFINx's matrix or :meth:`adopt`'s.

        Returns ``A``. Into the matrix of :meth:`adopt` the product writes the values
        directly, and the matrix's state is increased, so that a solver using it sets
        its preconditioner up again; into DOLFINx's the values are inserted (ghost
        rows to their owners).
        """
        fem.COUNTERS["matrix_assemblies"] += 1
        if A is self._own:
            self._S.mult(self._k_from(k), self._own_values)
            A.stateIncrease()
            return A
        values = self._products(k)
        A.zeroEntries()
        A.setValuesLocalCSR(self.indptr, self.indices, values, addv=PETSc.InsertMode.ADD_VALUES)
        A.assemble()
        return A

    def vector(self, k: np.ndarray, b: Any) -> Any:
        """``b = sum_c k_c E_c`` into the ghosted vector ``b``, ghosts added to their owners."""
        fem.COUNTERS["vector_assemblies"] += 1
        values = self._products(k)
        with b.localForm() as loc:
            loc.set(0.0)
            loc.array[self._entry_rows] = values
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        return b


def local_size(V: Any) -> int:
    """Unrolled local dofs (owned + ghosts) of a function space."""
    imap = V.dofmap.index_map
    return int(imap.size_local + imap.num_ghosts) * int(V.dofmap.index_map_bs)
