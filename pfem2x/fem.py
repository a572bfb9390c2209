"""Thin finite-element helpers over DOLFINx/PETSc: counted assembly and solves.

Every matrix assembly and linear solve in pfem2x goes through this module or is
counted in its :data:`COUNTERS` (the re-assemblies from element tensors of
:mod:`pfem2x.cellwise`), so that a run can report (and a test can assert) exactly
which operators a scene built: "simulate only the effects a scene calls for".
"""

from __future__ import annotations

from collections import Counter
from typing import Any

from pfem2x import compat
from pfem2x.compat import PETSc

__all__ = ["COUNTERS", "LinearSolver", "assemble_matrix", "divergence_text", "reset_counters"]

#: Process-wide counts: ``matrix_assemblies``, ``vector_assemblies``, ``solves``
#: (and ``error_integrals``: exact-solution error integrals of the flow diagnostics).
COUNTERS: Counter[str] = Counter()


def reset_counters() -> None:
    """Zero :data:`COUNTERS`."""
    COUNTERS.clear()


def assemble_matrix(a: Any, bcs: list | None = None, A: Any | None = None) -> Any:
    """Assemble a bilinear form (counted), reusing ``A`` when given."""
    COUNTERS["matrix_assemblies"] += 1
    return compat.assemble_matrix(a, bcs, A)


def assemble_vector(L: Any, b: Any, a: Any | None = None, bcs: list | None = None) -> Any:
    """Assemble a linear form into ``b`` (counted), with lifting/BCs when ``a, bcs`` given."""
    COUNTERS["vector_assemblies"] += 1
    return compat.assemble_vector(L, b, a, bcs)


#: BoomerAMG options set unless the user's PETSc options name them: HMIS coarsening,
#: extended+i interpolation, one level of aggressive coarsening (cheaper set-ups and
#: V-cycles for the pressure's Laplacian) and the smoother's sweeps in the natural order,
#: not C points then F points (a fifth cheaper V-cycles at the same iteration counts;
#: docs/BENCHMARKS.md, "The pressure solves' AMG")
HYPRE_OPTIONS = {
    "pc_hypre_boomeramg_coarsen_type": "HMIS",
    "pc_hypre_boomeramg_interp_type": "ext+i",
    "pc_hypre_boomeramg_agg_nl": "1",
    "pc_hypre_boomeramg_no_CF": "true",
}


def _options_unless_named(options: dict[str, str]) -> None:
    """Put ``options`` into PETSc's options database where the user did not name them."""
    opts = PETSc.Options()
    for key, value in options.items():
        if not opts.hasName(key):
            opts[key] = value


#: Why a KSP stopped short, by PETSc's (negative) converged reason
_DIVERGED = {
    -3: "no convergence in {its} iterations",
    -4: "the residual grew past the divergence tolerance",
    -5: "breakdown",
    -7: "a non-symmetric operator or preconditioner for CG",
    -8: "an indefinite preconditioner",
    -9: "NaN/Inf in the system",
    -10: "an indefinite operator",
    -11: "the preconditioner failed",
}


def divergence_text(reason: int, iterations: int) -> str:
    """What a KSP's negative converged ``reason`` means, with the reason's number.

    Parameters
    ----------
    reason
        ``KSP.getConvergedReason()`` of a solve that failed (< 0).
    iterations
        The solve's iteration count (named for an iteration limit).

    Returns
    -------
    str
        e.g. ``"no convergence in 5000 iterations, PETSc reason -3"``.
    """
    what = _DIVERGED.get(reason, "stopped")
    return f"{what.format(its=iterations)}, PETSc reason {reason}"


class LinearSolver:
    """A PETSc KSP with a pfem2x-chosen method, counted solves.

    Parameters
    ----------
    A:
        The assembled operator.
    kind:
        ``"cg"`` (SPD, AMG preconditioned), ``"gmres"`` (non-symmetric) or ``"lu"``.
    preconditioner:
        ``auto`` (cg: hypre where available, else gamg; gmres: ILU, block
        Jacobi/ILU in parallel), ``hypre``, ``gamg``, ``jacobi``, ``lu`` or ``none``.
    rtol:
        Relative tolerance of iterative solves.
    """

    def __init__(self, A: Any, kind: str = "cg", preconditioner: str = "auto", rtol: float = 1e-10):
        self.ksp = PETSc.KSP().create(A.getComm())
        self.ksp.setOperators(A)
        pc = self.ksp.getPC()
        if kind == "lu" or preconditioner == "lu":
            self.ksp.setType("preonly")
            pc.setType("lu")
        else:
            self.ksp.setType(kind)
            self.ksp.setTolerances(rtol=rtol, atol=1e-50, max_it=5000)
            self.ksp.setNormType(
                PETSc.KSP.NormType.UNPRECONDITIONED
                if kind == "gmres"
                else PETSc.KSP.NormType.DEFAULT
            )
            if kind == "gmres" and preconditioner == "auto":
                # Non-symmetric transport operators: PETSc's ILU (bjacobi/ILU in parallel).
                pc.setType("bjacobi" if A.getComm().getSize() > 1 else "ilu")
            else:
                pre = compat.preconditioner(preconditioner)
                if pre == "hypre":
                    pc.setType("hypre")
                    pc.setHYPREType("boomeramg")
                    _options_unless_named(HYPRE_OPTIONS)
                elif pre == "gamg":
                    pc.setType("gamg")
                elif pre == "jacobi":
                    pc.setType("jacobi")
                else:
                    pc.setType("none")
        if kind == "gmres":
            # classical Gram-Schmidt without re-orthogonalisation broke down (PETSc reason
            # -5) in the rising bubble's momentum solve at 50 x the capillary step limit;
            # re-orthogonalise when the test sees a loss (a user's PETSC_OPTIONS win)
            _options_unless_named({"ksp_gmres_cgs_refinement_type": "refine_ifneeded"})
        self.ksp.setFromOptions()
        self.last_iterations = 0

    def set_operator(self, A: Any) -> None:
        """Use a new (or re-assembled) operator."""
        self.ksp.setOperators(A)

    def solve(self, b: Any, x: Any, guess: bool | None = None, rtol: float | None = None) -> int:
        """Solve ``A x = b``; returns the iteration count; raises on divergence.

        ``guess``: ``True`` starts from the content of ``x``, ``False`` from 0 (the
        tolerance stays relative to the right-hand side, so a start near the solution
        saves iterations); ``None`` keeps the solver's setting (PETSc's default: 0).
        ``rtol``: the relative tolerance of this solve only (``None``: the solver's).
        """
        COUNTERS["solves"] += 1
        if guess is not None:
            self.ksp.setInitialGuessNonzero(bool(guess))
        if rtol is None:
            self.ksp.solve(b, x)
        else:
            keep = self.ksp.getTolerances()[0]
            self.ksp.setTolerances(rtol=rtol)
            try:
                self.ksp.solve(b, x)
            finally:
                self.ksp.setTolerances(rtol=keep)
        reason = self.ksp.getConvergedReason()
        self.last_iterations = int(self.ksp.getIterationNumber())
        if reason < 0:
            what = divergence_text(reason, self.last_iterations)
            raise FloatingPointError(f"linear solver diverged ({what})")
        return self.last_iterations

    def destroy(self) -> None:
        """Free PETSc objects."""
        self.ksp.destroy()
