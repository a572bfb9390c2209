"""Operators linear in a cellwise density: the sparse re-assembly equals DOLFINx's.

The Laplacian, the correction's gradient and the lumped mass of a DG0 coefficient, on
triangles and tetrahedra, serially and on 2 ranks (ghost rows go to their owners), and
the pressure step built on them: the same increment and corrected velocity as with
every form assembled by DOLFINx.
"""

import numpy as np
import pytest
import ufl

from pfem2x import cellwise, compat
from pfem2x.compat import MPI
from pfem2x.mesh import build_mesh, geometry_table
from pfem2x.physics.flow.projection import PressureProjection


def _domain(gdim: int):
    if gdim == 2:
        return build_mesh(
            MPI.COMM_WORLD, "rectangle", [[-0.5, -1.0], [0.5, 1.0]], [6, 9], "left/right"
        )
    return build_mesh(MPI.COMM_WORLD, "box", [[0, 0, 0], [1, 1, 2]], [3, 2, 4])


def _density(mesh, seed: int = 3):
    """A DG0 density in [1, 1000], from each cell's midpoint (the same on any partition)."""
    W0 = compat.function_space(mesh, 0, family="DG")
    rho = compat.dolfinx.fem.Function(W0)
    t = geometry_table(mesh)
    mid = t.coords.mean(axis=1)
    phase = np.sin(7.0 * mid[:, 0] + 3.0 * mid[:, 1] + seed) ** 2
    cells = compat.dofmap_array(W0)[:, 0]
    rho.x.array[cells] = 1.0 + 999.0 * phase
    return rho, cells[: t.num_cells_owned]


def _norm_diff(A, B) -> tuple[float, float]:
    C = A.copy()
    C.axpy(-1.0, B)
    return C.norm(), B.norm()


@pytest.mark.mpi
@pytest.mark.parametrize("gdim", [2, 3])
def test_cellwise_operators_equal_dolfinx_assembly(gdim):
    mesh = _domain(gdim).mesh
    rho, owned = _density(mesh)
    Q = compat.function_space(mesh, 1)
    V = compat.function_space(mesh, 1, shape=(gdim,))
    q, r = ufl.TrialFunction(Q), ufl.TestFunction(Q)
    w = ufl.TestFunction(V)
    t = geometry_table(mesh)
    qd, vd = compat.dofmap_array(Q), compat.dofmap_array(V)
    nq, nv = cellwise.local_size(Q), cellwise.local_size(V)
    k = 1.0 / rho.x.array[owned]

    results = []
    a_lap = compat.form((1.0 / rho) * ufl.dot(ufl.grad(q), ufl.grad(r)) * ufl.dx)
    A = compat.assemble_matrix(a_lap)
    lap = cellwise.CellwiseForm(*cellwise.p1_laplacian(t, qd), n_rows=nq, n_cols=nq)
    results.append(_norm_diff(lap.matrix(k, A.duplicate()), A))
    # adopted (the form's own matrix; under MPI its owned rows' blocks) and re-assembled
    # into it, from another coefficient than the adopted values'
    first = A.duplicate(copy=True)
    first.scale(3.0)
    own = lap.adopt(first)
    assert own is not first
    results.append(_norm_diff(lap.matrix(k, own), A))

    a_grad = compat.form(ufl.dot(ufl.grad(q), w) / rho * ufl.dx)
    G = compat.assemble_matrix(a_grad)
    grad = cellwise.CellwiseForm(*cellwise.p1_gradient(t, vd, qd, gdim), n_rows=nv, n_cols=nq)
    results.append(_norm_diff(grad.matrix(k, G.duplicate()), G))
    first = G.duplicate(copy=True)
    first.scale(3.0)
    own = grad.adopt(first)
    assert own is not first
    results.append(_norm_diff(grad.matrix(k, own), G))

    L_mass = compat.form(rho * ufl.dot(w, ufl.as_vector([1.0] * gdim)) * ufl.dx)
    b = compat.create_vector(L_mass)
    compat.assemble_vector(L_mass, b)
    mass = cellwise.CellwiseForm(*cellwise.p1_lumped_mass(t, vd, gdim), None, n_rows=nv)
    results.append(_norm_diff(mass.vector(rho.x.array[owned], b.duplicate()), b))

    # the norms are global: every rank asserts the same values
    for diff, ref in results:
        assert ref > 0.0
        assert diff <= 1e-13 * ref


@pytest.mark.mpi
def test_pressure_step_on_cellwise_operators_equals_the_forms():
    """Increment, correction and discrete projection: the same with either assembly."""
    mesh = _domain(2).mesh
    rho, owned = _density(mesh)
    Q = compat.function_space(mesh, 1)
    V = compat.function_space(mesh, 1, shape=(2,))
    dt_c = compat.dolfinx.fem.Constant(mesh, 0.1)
    bcs_u = []  # slip walls on every side, as a closed box's
    for axis, value in ((0, -0.5), (0, 0.5), (1, -1.0), (1, 1.0)):
        facets = compat.locate_boundary_facets(
            mesh, lambda x, a=axis, v=value: np.abs(x[a] - v) < 1e-10
        )
        bcs_u.append(compat.dirichlet_component(V, axis, facets, 0.0))
    x_nodes = V.tabulate_dof_coordinates()
    star = np.stack([np.sin(3 * x_nodes[:, 1]), np.cos(2 * x_nodes[:, 0])], axis=1).ravel()

    def step(cell_dofs):
        proj = PressureProjection(
            V, Q, 2, rho, None, ufl.dx(domain=mesh), dt_c, bcs_u, [], "velocity", True,
            "auto", 1e-12, lambda name: _NoTimer(), divergence_rtol=0.05,
            cell_dofs=cell_dofs,
        )  # fmt: skip
        proj.u_star.x.array[:] = star
        u = compat.dolfinx.fem.Function(V)
        p = compat.dolfinx.fem.Function(Q)
        for _ in range(2):  # the second pass re-assembles into the first's matrices
            proj.assemble_mass()
            proj.assemble_operator()
            proj.solve_increment()
            proj.correct(u, p, 0.1, mass_ready=True)
        return proj, u.x.array.copy(), p.x.array.copy()

    plain, u0, p0 = step(None)
    fast, u1, p1 = step(owned)
    assert not plain._cellwise and set(fast._cellwise) == {"laplacian", "mass", "gradient"}
    du = mesh.comm.allreduce(float(np.max(np.abs(u1 - u0))), op=MPI.MAX)
    # the pressure of a closed box up to a constant (the AMG sets it from round-off)
    n = len(fast.b_p.array_r)
    diff = (p1 - p0)[:n]
    shift = mesh.comm.allreduce(float(diff.sum()), op=MPI.SUM) / mesh.comm.allreduce(n, op=MPI.SUM)
    dp = mesh.comm.allreduce(float(np.max(np.abs(diff - shift))), op=MPI.MAX)
    scale = mesh.comm.allreduce(float(np.max(np.abs(u0))), op=MPI.MAX)
    assert scale > 0.1
    assert du <= 1e-8 * scale
    assert dp <= 1e-8 * mesh.comm.allreduce(float(np.max(np.abs(p0))), op=MPI.MAX)


class _NoTimer:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


@pytest.mark.mpi
def test_a_reassembly_reaches_the_solver_that_uses_the_matrix():
    """A re-assembly changes what the next solve of a kept solver sees.

    The form adopts DOLFINx's matrix as one over its own value arrays (under MPI, the
    owned rows' blocks, the ghost rows' values exchanged); a re-assembly writes only
    those arrays, and must still make a solver set its preconditioner up again: with
    an exact one that copies the matrix at its set-up (LU; on 2 ranks, LU of the
    gathered matrix) the solution halves when the coefficient doubles.
    """
    from pfem2x.compat import PETSc

    mesh = _domain(2).mesh
    rho, owned = _density(mesh)
    Q = compat.function_space(mesh, 1)
    q, r = ufl.TrialFunction(Q), ufl.TestFunction(Q)
    t = geometry_table(mesh)
    qd, nq = compat.dofmap_array(Q), cellwise.local_size(Q)
    k = 1.0 / rho.x.array[owned]
    # the Laplacian's element matrices plus a lumped mass: a regular operator
    E, rows, cols = cellwise.p1_laplacian(t, qd)
    E = E + (t.volume[: len(E)] / 3.0)[:, None, None] * np.eye(3)
    form = cellwise.CellwiseForm(E, rows, cols, n_rows=nq, n_cols=nq)
    A0 = compat.assemble_matrix(compat.form(ufl.dot(ufl.grad(q), ufl.grad(r)) * ufl.dx))
    A = form.adopt(A0)
    assert A is not A0
    assert form.matrix(k, A) is A
    ksp = PETSc.KSP().create(mesh.comm)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu" if mesh.comm.size == 1 else "redundant")
    b = A.createVecLeft()
    b.set(1.0)
    x1, x2 = A.createVecRight(), A.createVecRight()
    ksp.solve(b, x1)
    assert form.matrix(2.0 * k, A) is A
    ksp.setOperators(A)
    ksp.solve(b, x2)
    err = mesh.comm.allreduce(float(np.max(np.abs(2.0 * x2.array - x1.array))), op=MPI.MAX)
    ref = mesh.comm.allreduce(float(np.max(np.abs(x1.array))), op=MPI.MAX)
    assert ref > 0.0 and err <= 1e-8 * ref


def _sorted_structure(rows, cols, E, n_cols):
    """The structure by a stable sort of the element entries' keys (the reference)."""
    n, nr = rows.shape
    E = E.reshape(n, nr, -1)
    key = (rows.astype(np.int64)[:, :, None] * n_cols + cols[:, None, :]).reshape(-1)
    order = np.argsort(key, kind="stable")
    keys = key[order]
    first = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]])
    unique = keys[first]
    return (
        unique // n_cols,
        unique % n_cols,
        np.append(first, len(keys)),
        order // E[0].size,
        E.ravel()[order],
    )


@pytest.mark.parametrize("case", ["random", "p1"])
def test_entry_structure_is_the_stable_sort_of_the_entry_keys(case):
    """Distinct entries in (row, column) order, each one's cells ascending, its values."""
    from pfem2x.particles import _kernels as K

    rng = np.random.default_rng(5)
    if case == "random":  # repeated rows and (row, column) pairs inside a cell too
        n, nr, nc, n_rows, n_cols = 300, 4, 3, 40, 25
        rows = rng.integers(0, n_rows, (n, nr))
        cols = rng.integers(0, n_cols, (n, nc))
        E = rng.standard_normal((n, nr, nc))
    else:
        d = build_mesh(MPI.COMM_SELF, "rectangle", [[0, 0], [1, 2]], [7, 11], "left/right")
        Q = compat.function_space(d.mesh, 1)
        V = compat.function_space(d.mesh, 1, shape=(2,))
        E, rows, cols = cellwise.p1_gradient(
            geometry_table(d.mesh), compat.dofmap_array(V), compat.dofmap_array(Q), 2
        )
        n_rows, n_cols = cellwise.local_size(V), cellwise.local_size(Q)
        rows, cols = rows.astype(np.int64), cols.astype(np.int64)
    indptr, indices, entry_rows, s_ptr, s_cell, s_val = K.entry_structure(
        rows, cols, np.ascontiguousarray(E.reshape(len(rows), rows.shape[1], -1)), n_rows
    )
    ref_rows, ref_cols, ref_ptr, ref_cell, ref_val = _sorted_structure(rows, cols, E, n_cols)
    assert np.array_equal(entry_rows, ref_rows)
    assert np.array_equal(indices, ref_cols)
    assert np.array_equal(indptr, np.searchsorted(ref_rows, np.arange(n_rows + 1)))
    assert np.array_equal(s_ptr, ref_ptr)
    assert np.array_equal(s_cell, ref_cell)
    assert np.array_equal(s_val, ref_val)
