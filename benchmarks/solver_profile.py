"""Where a run's linear-solver time goes: set-up and solve of every kind of KSP.

Runs ``pfem2x run SCENE`` in this process (under ``mpirun`` on every rank) with
the solvers timed: each :class:`pfem2x.fem.LinearSolver` solve is split into its
preconditioner set-up (``KSPSetUp``, timed on its own before the solve) and the
solve, keyed by KSP and PC type (``cg/hypre``: the pressure; ``cg/jacobi``: the
viscous predictor), and the discrete projection's GMRES (``flow.divergence_rtol``)
is timed as a whole (its preconditioner is the pressure solve's AMG, already set
up). Rank 0 prints a markdown table: seconds, solves and iterations, and the
run's wall time, ``solve`` timer and chosen metrics from ``summary.json``.

PETSc options from ``PETSC_OPTIONS`` apply as in any run, so solver options can
be compared one run each (one run at a time on an otherwise idle machine)::

    python benchmarks/solver_profile.py rayleigh-taylor --metric tip_error_tau2
    PETSC_OPTIONS="-pc_hypre_boomeramg_agg_nl 0" \\
        python benchmarks/solver_profile.py rayleigh-taylor --metric tip_error_tau2
    mpirun -n 2 python benchmarks/solver_profile.py rayleigh-taylor

``--time MODULE:NAME`` (repeatable) also times every call of a function or method of
the run, as the run's code reaches it: ``pfem2x.particles:project`` (the flow frames
call the package's name), ``pfem2x.particles.cloud:Cloud.sort_by_cell``::

    python benchmarks/solver_profile.py rayleigh-taylor --time pfem2x.particles:project

Pictures, fields and particle files are off; ``--set KEY=VALUE`` adds overrides.
Timings are for comparing options, not targets: those live in ``rt_profile.py``
and ``step_cost.py``.
"""

from __future__ import annotations

import argparse
import collections
import importlib
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from mpi4py import MPI

from pfem2x import fem
from pfem2x.cli import main as pfem2x_main
from pfem2x.physics.flow import projection

QUIET = ("output.every=0", "output.png=false", "output.fields=false", "output.particles=false")


class SolverClock:
    """Seconds, solves and iterations per solver kind, while :meth:`install` is in effect."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = collections.defaultdict(float)
        self.solves: collections.Counter[str] = collections.Counter()
        self.iterations: collections.Counter[str] = collections.Counter()

    def install(self) -> None:
        """Wrap the solve methods of :class:`fem.LinearSolver` and the discrete projection."""
        clock = self
        solve = fem.LinearSolver.solve
        discrete = projection._DiscreteProjection.solve

        def timed_solve(self: fem.LinearSolver, b: Any, x: Any, *args: Any, **kw: Any) -> int:
            key = f"{self.ksp.getType()}/{self.ksp.getPC().getType()}"
            t0 = time.perf_counter()
            self.ksp.setUp()
            t1 = time.perf_counter()
            its = solve(self, b, x, *args, **kw)
            clock.add(key, t1 - t0, time.perf_counter() - t1, its)
            return its

        def timed_discrete(self: Any, b: Any, x: Any, *args: Any, **kw: Any) -> int:
            t0 = time.perf_counter()
            its = discrete(self, b, x, *args, **kw)
            clock.add("discrete/gmres", 0.0, time.perf_counter() - t0, its)
            return its

        fem.LinearSolver.solve = timed_solve  # type: ignore[method-assign]
        projection._DiscreteProjection.solve = timed_discrete  # type: ignore[method-assign]

    def add(self, key: str, setup: float, solve: float, its: int) -> None:
        """Count one solve of ``key``."""
        self.seconds[f"{key} setup"] += setup
        self.seconds[f"{key} solve"] += solve
        self.solves[key] += 1
        self.iterations[key] += its

    def table(self) -> str:
        """Markdown rows: kind, set-up s, solve s, solves, iterations per solve."""
        rows = [
            "| solver | set-up s | solve s | solves | iterations per solve |",
            "|---|---:|---:|---:|---:|",
        ]
        for key in sorted(self.solves):
            n = self.solves[key]
            rows.append(
                f"| {key} | {self.seconds[key + ' setup']:.2f} | "
                f"{self.seconds[key + ' solve']:.2f} | {n} | {self.iterations[key] / n:.1f} |"
            )
        return "\n".join(rows)


class CallClock:
    """Seconds and calls of named functions (``MODULE:NAME``), while installed."""

    def __init__(self, names: list[str]) -> None:
        self.names = names
        self.seconds: dict[str, float] = collections.defaultdict(float)
        self.calls: collections.Counter[str] = collections.Counter()
        self._undo: list[tuple[Any, str, Any]] = []

    def install(self) -> None:
        """Wrap each named function; ``ValueError`` naming one that does not resolve."""
        for name in self.names:
            mod, _, path = name.partition(":")
            try:
                parent = importlib.import_module(mod)
                *head, last = path.split(".")
                for part in head:
                    parent = getattr(parent, part)
                fn = getattr(parent, last)
            except (ImportError, AttributeError, ValueError) as exc:
                self.uninstall()
                raise ValueError(f"--time {name}: {exc}") from None
            if not callable(fn):
                self.uninstall()
                raise ValueError(f"--time {name}: not a function")
            raw = vars(parent).get(last)  # None: inherited, removed again afterwards
            self._undo.append((parent, last, raw))
            timed = self._timed(name, fn)
            if isinstance(raw, (staticmethod, classmethod)):
                timed = staticmethod(timed)  # fn is bound already (or needs no instance)
            setattr(parent, last, timed)

    def _timed(self, name: str, fn: Any) -> Any:
        clock = self

        def timed(*args: Any, **kw: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kw)
            finally:
                clock.seconds[name] += time.perf_counter() - t0
                clock.calls[name] += 1

        return timed

    def uninstall(self) -> None:
        """Put the original functions back."""
        for parent, last, orig in reversed(self._undo):
            if orig is None:
                delattr(parent, last)
            else:
                setattr(parent, last, orig)
        self._undo.clear()

    def table(self) -> str:
        """Markdown rows: function, calls, seconds."""
        rows = ["| function | calls | s |", "|---|---:|---:|"]
        rows += [f"| {n} | {self.calls[n]} | {self.seconds[n]:.3f} |" for n in self.names]
        return "\n".join(rows)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="built-in scene name or scene file")
    ap.add_argument("--variant", default=None, help="the scene's variant")
    ap.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--metric", action="append", default=[], help="summary metric to print")
    ap.add_argument(
        "--time", action="append", default=[], metavar="MODULE:NAME", help="also time this"
    )
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Run the scene with the solvers timed; rank 0 prints the table."""
    args = parse_args(argv)
    comm = MPI.COMM_WORLD
    calls = CallClock(args.time)
    try:
        calls.install()
    except ValueError as exc:
        if comm.rank == 0:
            print(f"error: {exc}", file=sys.stderr)
        return 2
    clock = SolverClock()
    clock.install()
    tmp = tempfile.mkdtemp(prefix="solver_profile_") if comm.rank == 0 else None
    out = Path(comm.bcast(tmp, root=0)) / "run"
    cmd = ["run", args.scene, "--out", str(out), "--quiet", "--overwrite"]
    if args.variant:
        cmd += ["--variant", args.variant]
    for s in [*QUIET, *args.sets]:
        cmd += ["--set", s]
    try:
        code = pfem2x_main(cmd)
    except SystemExit as exc:  # the command line ends with sys.exit
        code = exc.code
    finally:
        calls.uninstall()
    if code not in (0, None):
        return int(code) if isinstance(code, int) else 1
    if comm.rank == 0:
        s = json.loads((out / "summary.json").read_text())
        print(clock.table())
        if args.time:
            print("\n" + calls.table())
        line = f"\nwall {s['wall_seconds']:.2f} s, solve timer {s['timings'].get('solve', 0):.2f} s"
        for m in args.metric:
            line += f", {m} {s['metrics'].get(m)}"
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
