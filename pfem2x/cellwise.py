r"""P1 operators linear in a cellwise-constant coefficient, re-assembled as one sparse product.

A bilinear form :math:`\int k\,B(q, r)` on affine simplices, with :math:`k` constant in
each cell (a DG0 density) and :math:`B` of P1 functions, is
:math:`A(k) = \sum_c k_c E_c`: the element matrices :math:`E_c` of :math:`k = 1` do not
change while :math:`k` does. :class:`CellwiseForm` computes them once, with the map from
every element entry to its place in the matrix (a sparse matrix :math:`S` from the
owned cells' coefficients to the rows of the assembled operator, local rows and ghost
rows both). The form adopts DOLFINx's first assembly of the same form as a matrix of
its own (:meth:`CellwiseForm.adopt`): on one process over the value array that
:math:`S k` writes, under MPI over the owned rows' diagonal and off-diagonal blocks,
which a re-ordered :math:`S k` writes, the ghost rows' values then added to their
owners' entries by one scatter (as PETSc's assembly adds them in DOLFINx's own
assembler). A re-assembly is that product (and exchange) alone; into another matrix
of the form's layout it is the product and one insertion. The same for a linear form
into a ghosted vector.

The element tensors of the operators the flow frames re-assemble every pass
(:func:`p1_laplacian`, :func:`p1_gradient`, :func:`p1_lumped_mass`) are exact for
P1 on affine cells, so a re-assembly equals DOLFINx's to round-off
(``tests/test_cellwise.py`` compares both, serially and on 2 ranks).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import fem
from pfem2x.compat import MPI, PETSc
from pfem2x.mesh import basis_gradients
from pfem2x.particles import _kernels as K

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
        Local unrolled rows and columns (owned + ghosts). The structure is built by a
        counting sort of the entries by row and an insertion sort of each row's few
        entries by column (:func:`pfem2x.particles._kernels.entry_structure`), in the
        order of a stable sort of their keys ``row * n_cols + col``.
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
        E = np.ascontiguousarray(E.reshape(n, nr, -1), dtype=np.float64)
        cols = np.zeros((n, 1), dtype=np.int64) if cols is None else cols
        indptr, indices, entry_rows, s_ptr, s_cell, s_val = K.entry_structure(
            np.ascontiguousarray(rows, dtype=np.int64),
            np.ascontiguousarray(cols, dtype=np.int64),
            E,
            int(n_rows),
        )
        #: the structure of the re-assembled rows (local indices, CSR)
        self.indptr = indptr.astype(PETSc.IntType)
        self.indices = indices.astype(PETSc.IntType)
        #: the row of each entry (a vector's entries: one per row that an owned cell touches)
        self._entry_rows = entry_rows
        self.n_rows = n_rows
        # S: the structure's entries from the cells' coefficients, (n_entries, n_owned);
        # PETSc uses these arrays in place (kept here): each row's cells ascend
        self._csr = (
            s_ptr.astype(PETSc.IntType),
            s_cell.astype(PETSc.IntType, copy=False),
            s_val.astype(PETSc.ScalarType, copy=False),
        )
        self._S = PETSc.Mat().createAIJWithArrays(
            (len(indices), n), self._csr, comm=PETSc.COMM_SELF
        )
        self._k = PETSc.Vec().createSeq(n, comm=PETSc.COMM_SELF)
        self._values = PETSc.Vec().createSeq(len(indices), comm=PETSc.COMM_SELF)
        #: one process: the matrix over the value array :attr:`_own_values` (see adopt)
        self._own: Any = None
        self._own_values: Any = None
        #: MPI: the re-ordered S, the split arrays, the ghost rows' scatter (see adopt)
        self._S_split: Any = None
        self._csr_split: Any = None
        self._split: Any = None
        self._exchange: Any = None

    def _k_from(self, k: np.ndarray) -> Any:
        self._k.array[:] = k
        return self._k

    def _products(self, k: np.ndarray) -> np.ndarray:
        self._S.mult(self._k_from(k), self._values)
        return self._values.array_r

    def adopt(self, A: Any) -> Any:
        """A matrix of this form's own with ``A``'s values, or ``A`` itself.

        ``A`` is DOLFINx's assembled matrix of the form. The returned matrix holds a copy
        of its values in an array that :meth:`matrix` then writes: a re-assembly is the
        product alone (and under MPI one exchange of the ghost rows' values), without an
        insertion. Adopt the matrix at its first assembly, so that a solver sees one
        matrix object for the whole run (a preconditioner that re-uses its set-up for a
        re-assembled matrix, as GAMG's interpolation, behaves as with DOLFINx's). When
        ``A``'s structure does not hold this form's entries, ``A`` itself is returned
        and :meth:`matrix` inserts into it (collective).
        """
        if A.getComm().getSize() > 1:
            return self._adopt_split(A)
        indptr, indices, values = A.getValuesCSR()
        if not (np.array_equal(indptr, self.indptr) and np.array_equal(indices, self.indices)):
            return A
        values = np.array(values, dtype=PETSc.ScalarType)
        self._own = PETSc.Mat().createAIJWithArrays(
            A.getSizes(), (self.indptr, self.indices, values), comm=PETSc.COMM_SELF
        )
        self._own_values = PETSc.Vec().createWithArray(values, comm=PETSc.COMM_SELF)
        return self._own

    def _adopt_split(self, A: Any) -> Any:
        """:meth:`adopt` under MPI: the owned rows' diagonal and off-diagonal blocks.

        The matrix is PETSc's MPI AIJ over two value arrays of the form's own (the
        owned rows' entries in the owned columns, then in the others: ``A``'s
        structure, which also holds the entries of the other ranks' cells). The product
        :math:`S k` is re-ordered to write the owned rows' values straight into them
        and the ghost rows' values after them; one scatter adds those to their owners'
        entries, as PETSc's assembly adds a matrix's off-process values.
        """
        comm = A.getComm()
        mpi = comm.tompi4py()
        (m, _), (_, N) = A.getSizes()
        rstart, rend = A.getOwnershipRange()
        cstart, cend = A.getOwnershipRangeColumn()
        indptr, gcols, values = A.getValuesCSR()  # owned rows, global columns ascending
        gcols = np.asarray(gcols, dtype=np.int64)
        grows = np.repeat(np.arange(m, dtype=np.int64), np.diff(indptr))
        keys = grows * N + gcols  # ascending
        diag = (gcols >= cstart) & (gcols < cend)
        nnz, nd = len(keys), int(np.count_nonzero(diag))
        place = np.empty(nnz, dtype=np.int64)  # A's entry -> its place in the value array
        place[np.argsort(~diag, kind="stable")] = np.arange(nnz)
        # this form's entries (local rows and columns) as global entries
        rmap, cmap = A.getLGMap()
        g = np.asarray(rmap.apply(self._entry_rows.astype(PETSc.IntType)), dtype=np.int64)
        gc = np.asarray(cmap.apply(self.indices), dtype=np.int64)
        owned = (g >= rstart) & (g < rend)
        found, at = _lookup(keys, (g[owned] - rstart) * N + gc[owned])
        # the ghost rows' entries: their places in their owners' value arrays
        ranges = np.asarray(A.getOwnershipRanges(), dtype=np.int64)
        gg, ggc = g[~owned], gc[~owned]
        dest = np.searchsorted(ranges, gg, side="right") - 1
        by_dest = np.argsort(dest, kind="stable")
        send = np.bincount(dest, minlength=len(ranges) - 1).astype(np.int64)
        recv = np.asarray(mpi.alltoall(send.tolist()), dtype=np.int64)
        asked = np.empty(int(recv.sum()), dtype=np.int64)
        wanted = ((gg - ranges[dest]) * N + ggc)[by_dest]
        mpi.Alltoallv([wanted, send], [asked, recv])
        found_asked, at_asked = _lookup(keys, asked)
        offset = mpi.exscan(nnz) or 0
        answer = offset + place[at_asked] if found_asked else np.zeros_like(asked)
        there = np.empty(len(gg), dtype=np.int64)
        mpi.Alltoallv([answer, recv], [there, send])
        ok = found and found_asked
        if not mpi.allreduce(ok, op=MPI.LAND):
            return A
        ghost_places = np.empty_like(there)
        ghost_places[by_dest] = there
        # S re-ordered: owned entries to their places, ghost entries after the nnz
        target = np.empty(len(g), dtype=np.int64)
        target[owned] = place[at]
        target[~owned] = nnz + np.arange(len(gg))
        n_cells = len(self._k.array_r)
        self._S_split, self._csr_split = _rows_moved(self._csr, target, nnz + len(gg), n_cells)
        full = np.zeros(nnz + len(gg), dtype=PETSc.ScalarType)
        full[place] = values
        own = full[:nnz]
        d_ind = np.zeros(m + 1, dtype=PETSc.IntType)
        o_ind = np.zeros(m + 1, dtype=PETSc.IntType)
        np.cumsum(np.bincount(grows[diag], minlength=m), out=d_ind[1:])
        np.cumsum(np.bincount(grows[~diag], minlength=m), out=o_ind[1:])
        self._split = (
            (d_ind, (gcols[diag] - cstart).astype(PETSc.IntType), own[:nd]),
            (o_ind, gcols[~diag].astype(PETSc.IntType), own[nd:]),
        )
        self._own = PETSc.Mat().createAIJWithArrays(A.getSizes(), self._split, comm=comm)
        self._own_values = PETSc.Vec().createWithArray(full, comm=PETSc.COMM_SELF)
        ghosts = PETSc.Vec().createWithArray(full[nnz:], comm=PETSc.COMM_SELF)
        owners = PETSc.Vec().createWithArray(own, size=(nnz, PETSc.DECIDE), comm=comm)
        places = PETSc.IS().createGeneral(ghost_places.astype(PETSc.IntType), comm=PETSc.COMM_SELF)
        self._exchange = (PETSc.Scatter().create(ghosts, None, owners, places), ghosts, owners)
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
            if self._exchange is None:
                self._S.mult(self._k_from(k), self._own_values)
            else:
                self._S_split.mult(self._k_from(k), self._own_values)
                scatter, ghosts, owners = self._exchange
                scatter.scatter(ghosts, owners, PETSc.InsertMode.ADD, PETSc.ScatterMode.FORWARD)
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


def _lookup(keys: np.ndarray, wanted: np.ndarray) -> tuple[bool, np.ndarray]:
    """Whether every ``wanted`` key is in the ascending ``keys``, and where."""
    at = np.searchsorted(keys, wanted)
    inside = at < len(keys)
    found = bool(np.all(inside)) and bool(np.array_equal(keys[at[inside]], wanted))
    return found, np.where(inside, at, 0)


def _rows_moved(csr: tuple, target: np.ndarray, n_rows: int, n_cols: int) -> tuple[Any, tuple]:
    """The sparse matrix whose row ``target[i]`` is row ``i`` of ``csr`` (others empty).

    Returns the matrix and its CSR arrays, which PETSc uses in place (keep them).
    """
    indptr, cols, vals = csr
    lengths = np.zeros(n_rows, dtype=np.int64)
    lengths[target] = np.diff(indptr)
    new_ptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(lengths, out=new_ptr[1:])
    order = np.argsort(target)  # the source rows in their new order
    starts = np.asarray(indptr[:-1], dtype=np.int64)[order]
    n = np.diff(indptr)[order]
    take = np.repeat(starts - np.cumsum(n) + n, n) + np.arange(int(n.sum()))
    moved = (
        new_ptr.astype(PETSc.IntType),
        np.ascontiguousarray(cols[take]),
        np.ascontiguousarray(vals[take]),
    )
    return PETSc.Mat().createAIJWithArrays((n_rows, n_cols), moved, comm=PETSc.COMM_SELF), moved


def local_size(V: Any) -> int:
    """Unrolled local dofs (owned + ghosts) of a function space."""
    imap = V.dofmap.index_map
    return int(imap.size_local + imap.num_ghosts) * int(V.dofmap.index_map_bs)
