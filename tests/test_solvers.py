"""Linear solvers: one solve's own tolerance; pfem2x's BoomerAMG options, and the user's PETSc
options winning over them.

The options must reach hypre: aggressive coarsening changes the iteration count of a CG
solve of a Poisson problem, so the counts with pfem2x's choice and with the user's
``agg_nl 0`` differ, and the latter equals that of PETSc's defaults. The smoother's order
(``no_CF``) changes the solve's final residual.
"""

import pytest
import ufl

from pfem2x import compat, fem
from pfem2x.compat import MPI, PETSc

needs_hypre = pytest.mark.skipif(not compat.has_hypre(), reason="PETSc without hypre")

KEYS = tuple(fem.HYPRE_OPTIONS)


@pytest.fixture
def clean_options():
    """Take pfem2x's hypre keys out of PETSc's options database, before and after."""
    opts = PETSc.Options()
    saved = {k: opts.getString(k) for k in KEYS if opts.hasName(k)}
    for k in KEYS:
        opts.delValue(k)
    yield opts
    for k in KEYS:
        opts.delValue(k)
    for k, v in saved.items():
        opts[k] = v


_ALIVE: list = []


def poisson(n: int = 64):
    """A Poisson operator with a small mass shift (SPD) and a right-hand side of ones."""
    mesh = compat.dolfinx.mesh.create_unit_square(MPI.COMM_SELF, n, n)
    V = compat.function_space(mesh)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    a = compat.form((ufl.inner(ufl.grad(u), ufl.grad(v)) + 1e-3 * u * v) * ufl.dx)
    L = compat.form(v * ufl.dx)
    A = compat.assemble_matrix(a)
    b = compat.create_vector(L)
    compat.assemble_vector(L, b)
    _ALIVE.append((mesh, a, L))  # (DOLFINx 0.11: the vectors' communicator is the mesh's)
    return A, b


def iterations(A, b) -> int:
    return solve(A, b)[0]


def solve(A, b) -> tuple[int, float]:
    """Iterations and final residual norm of a hypre-preconditioned CG solve."""
    solver = fem.LinearSolver(A, "cg", "hypre", rtol=1e-10)
    x = b.duplicate()
    try:
        return solver.solve(b, x), solver.ksp.getResidualNorm()
    finally:
        solver.destroy()
        x.destroy()


def test_a_solve_that_stops_short_says_why():
    """The iteration limit and a NaN are named in the error, with PETSc's reason."""
    A, b = poisson(32)
    solver = fem.LinearSolver(A, "cg", "jacobi", rtol=1e-12)
    solver.ksp.setTolerances(max_it=3)
    x = b.duplicate()
    try:
        with pytest.raises(
            FloatingPointError,
            match=r"no convergence in 3 iterations, PETSc "
            r"reason -3",
        ):
            solver.solve(b, x, guess=False)
        b.set(float("nan"))
        with pytest.raises(FloatingPointError, match=r"NaN/Inf in the system, PETSc reason -9"):
            solver.solve(b, x, guess=False)
    finally:
        solver.destroy()
        x.destroy()
    assert fem.divergence_text(-99, 7) == "stopped, PETSc reason -99"


def test_one_solve_with_its_own_tolerance():
    """``solve(..., rtol=r)``: that solve stops at r, the solver keeps its own tolerance."""
    A, b = poisson(32)
    solver = fem.LinearSolver(A, "cg", "jacobi", rtol=1e-10)
    x = b.duplicate()
    try:
        tight = solver.solve(b, x)
        loose = solver.solve(b, x, guess=False, rtol=1e-3)
        assert solver.ksp.getTolerances()[0] == 1e-10
        assert solver.solve(b, x, guess=False) == tight
        assert 0 < loose < 0.7 * tight, (loose, tight)
    finally:
        solver.destroy()
        x.destroy()


@needs_hypre
def test_pfem2x_options_are_set_and_reach_hypre(clean_options):
    A, b = poisson()
    ours = iterations(A, b)
    for key, value in fem.HYPRE_OPTIONS.items():
        assert clean_options.getString(key) == value
    clean_options["pc_hypre_boomeramg_agg_nl"] = "0"
    without_aggressive = iterations(A, b)
    assert clean_options.getString("pc_hypre_boomeramg_agg_nl") == "0"
    assert ours != without_aggressive


@needs_hypre
def test_smoother_order_reaches_hypre(clean_options):
    """``no_CF``: the same problem's solve ends elsewhere with C/F-ordered sweeps."""
    A, b = poisson()
    natural = solve(A, b)
    assert clean_options.getString("pc_hypre_boomeramg_no_CF") == "true"
    clean_options["pc_hypre_boomeramg_no_CF"] = "false"
    cf_ordered = solve(A, b)
    assert natural != cf_ordered, (natural, cf_ordered)


@needs_hypre
def test_user_options_win(clean_options):
    A, b = poisson()
    clean_options["pc_hypre_boomeramg_coarsen_type"] = "Falgout"
    clean_options["pc_hypre_boomeramg_interp_type"] = "classical"
    clean_options["pc_hypre_boomeramg_agg_nl"] = "0"
    clean_options["pc_hypre_boomeramg_no_CF"] = "false"
    users = iterations(A, b)
    assert clean_options.getString("pc_hypre_boomeramg_coarsen_type") == "Falgout"
    # PETSc's own defaults are the user's choice here: the same iterations
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.setTolerances(rtol=1e-10, atol=1e-50, max_it=5000)
    ksp.getPC().setType("hypre")
    ksp.getPC().setHYPREType("boomeramg")
    for k in KEYS:
        clean_options.delValue(k)
    x = b.duplicate()
    ksp.solve(b, x)
    assert ksp.getConvergedReason() > 0
    assert ksp.getIterationNumber() == users
    ksp.destroy()
