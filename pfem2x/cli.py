"""Command line: ``pfem2x run | check | scenes | study``.

Exit codes: 0 ok, 2 bad input (one ``error:`` line on stderr naming the key
or file), 3 the simulation diverged (or one of the scene's expressions could not be
evaluated at a later time), 130 / 143 interrupted by SIGINT / SIGTERM
(after writing a checkpoint; continue with ``pfem2x run --resume DIR``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections.abc import MutableMapping
from pathlib import Path

from pfem2x import __version__

__all__ = ["entry", "main"]


#: the commands (the sub-parsers of :func:`_parser`)
_COMMANDS = ("run", "check", "scenes", "study")


class _Parser(argparse.ArgumentParser):
    #: the arguments being parsed (for the help hint of an error)
    argv: list[str] = []

    def error(self, message: str) -> None:  # one line, exit 2, no usage dump
        words = self.prog.split()
        if len(words) == 1:  # the main parser (also for a command's unknown options)
            words += [a for a in self.argv[:1] if a in _COMMANDS]
        print(f"error: {message} (see `{' '.join(words)} --help`)", file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog="pfem2x", description="PFEM-2 particle-mesh flow solver on DOLFINx")
    p.add_argument("--version", action="version", version=f"pfem2x {__version__}")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=_Parser)
    r = sub.add_parser("run", help="run a scene")
    r.add_argument("scene", nargs="?", help="a scene file (.toml) or a built-in scene name")
    r.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a scene key"
    )
    r.add_argument("--variant", help="apply the scene's [variants.NAME] (e.g. small)")
    r.add_argument("--out", help="output folder (default runs/SCENE)")
    r.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    r.add_argument("--quiet", action="store_true", help="no progress bar or messages")
    r.add_argument(
        "--resume",
        metavar="DIR",
        help="continue the interrupted run in DIR from its checkpoint (same number of ranks)",
    )
    c = sub.add_parser("check", help="validate a scene (and build its mesh) without running")
    c.add_argument("scene", help="a scene file (.toml) or a built-in scene name")
    c.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override a scene key"
    )
    c.add_argument("--variant", help="apply the scene's [variants.NAME] (e.g. small)")
    sub.add_parser("scenes", help="list built-in scenes")
    from pfem2x.study import add_study_parser  # noqa: PLC0415

    add_study_parser(sub)
    return p


#: Open MPI settings of a process started without a launcher (a singleton), set where the
#: environment does not name them: the ob1 messaging layer (no UCX start-up, which a
#: single process has no use for) and no supporting daemon (no MPI_Comm_spawn). MPI's
#: start then takes about 0.02 s instead of 0.3 s (docs/BENCHMARKS.md, "MPI's start in a
#: serial run").
SINGLETON_MPI = {"OMPI_MCA_pml": "ob1", "OMPI_MCA_ess_singleton_isolated": "1"}

#: Open MPI settings of processes that ``mpirun`` started all on one node: the ob1
#: messaging layer (shared memory between the node's processes) instead of UCX, whose
#: start-up takes about 0.2 s of every rank's start. Processes spread over several nodes
#: keep UCX (their network's layer).
ONE_NODE_MPI = {"OMPI_MCA_pml": "ob1"}

#: environment variables that a launcher sets in the processes it starts
LAUNCHED = ("OMPI_COMM_WORLD_SIZE", "PMIX_RANK", "PMI_RANK", "PMI_SIZE")


def quick_mpi_defaults(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """Put Open MPI's quick-start settings into ``environ`` (``os.environ``).

    :data:`SINGLETON_MPI` without a launcher; :data:`ONE_NODE_MPI` when ``mpirun`` started
    every process of the run on this node (Open MPI's ``OMPI_COMM_WORLD_LOCAL_SIZE``
    equals ``OMPI_COMM_WORLD_SIZE``: the same on every process, so all of them choose
    alike); nothing for other launchers or several nodes. Call before MPI is initialised
    (the first import of ``mpi4py.MPI``); a variable the environment already has (an
    ``mpirun --mca`` option included) is kept. Returns the variables set.
    """
    env = os.environ if environ is None else environ
    if not any(k in env for k in LAUNCHED):
        wanted = SINGLETON_MPI
    elif env.get("OMPI_COMM_WORLD_LOCAL_SIZE", "") == env.get("OMPI_COMM_WORLD_SIZE"):
        wanted = ONE_NODE_MPI
    else:
        return {}
    new = {k: v for k, v in wanted.items() if k not in env}
    env.update(new)
    return new


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``pfem2x`` console script."""
    parser = _parser()
    parser.argv = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(parser.argv)
    if args.cmd == "scenes":
        return _scenes()
    if args.cmd == "study":  # a serial driver: no MPI, no DOLFINx
        from pfem2x.study import study_main  # noqa: PLC0415

        return study_main(args)
    if "mpi4py.MPI" not in sys.modules:
        quick_mpi_defaults()
    from mpi4py import MPI  # noqa: PLC0415

    from pfem2x.expr import ExpressionError  # noqa: PLC0415
    from pfem2x.scene import SceneError, load_scene  # noqa: PLC0415

    comm = MPI.COMM_WORLD
    try:
        if args.cmd == "run" and args.resume is not None:
            return _resume(args, comm)
        if args.scene is None:
            raise SceneError("run: give a scene, or --resume DIR")
        scene = load_scene(args.scene, args.set, args.variant)
        # DOLFINx is imported only once the scene is known to be sane.
        from pfem2x.runner import Simulation, build_domain, make_solver  # noqa: PLC0415
        from pfem2x.timestep import make_time_control  # noqa: PLC0415

        if args.cmd == "check":
            domain = build_domain(scene, comm)
            solver = make_solver(scene, domain)
            tc = make_time_control(scene, domain, solver)
            dt, steps = tc.dt, tc.steps
            if comm.rank == 0:
                taken = f"; [frames.{scene.frame}]: " + ", ".join(scene.frame_keys)
                auto = "; auto: " + ", ".join(
                    f"{k} = {json.dumps(v)}" for k, v in solver.auto_keys.items()
                )
                plan = f"{steps} steps of dt = {dt:.4g}"
                if tc.adaptive:
                    plan = (
                        f"first dt = {dt:.4g} ({steps} steps at it), re-evaluated every step "
                        f"from time.courant = {tc.courant:g}"
                    )
                print(
                    f"ok: {scene.name} ({scene.physics}, {scene.frame}), "
                    f"{domain.num_cells_global()} cells, {plan}"
                    + (taken if scene.frame_keys else "")
                    + (auto if solver.auto_keys else "")
                )
            return 0
        out = Path(args.out) if args.out else None  # None: runs/<scene name>, checked
        sim = Simulation(scene, out, comm, quiet=args.quiet, overwrite=args.overwrite)
        result = sim.run()
        return result.exit_code
    except (SceneError, ExpressionError) as exc:  # bad input, an expression's key named
        if comm.rank == 0:
            print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if comm.rank == 0:
            print("error: interrupted", file=sys.stderr)
        return 130


def entry() -> None:
    """The ``pfem2x`` console script and ``python -m pfem2x``: :func:`main`, then the exit.

    After a ``run`` or ``check`` (MPI, PETSc, DOLFINx and numba loaded) the process
    finalises PETSc and MPI and ends without the interpreter's teardown of every
    module, which takes about a second with these libraries loaded; every output
    file is closed by then. Other commands, and a :func:`main` that raises, exit
    as usual.
    """
    code = main()
    if "mpi4py.MPI" in sys.modules:
        _quick_exit(code)
    sys.exit(code)


def _quick_exit(code: int) -> None:
    """Flush, finalise PETSc (its ``-log_view`` output) and MPI, end the process."""
    sys.stdout.flush()
    sys.stderr.flush()
    petsc = sys.modules.get("petsc4py.PETSc")
    finalize = getattr(petsc, "_finalize", None)
    if finalize is not None:
        finalize()
    from mpi4py import MPI  # noqa: PLC0415

    if MPI.Is_initialized() and not MPI.Is_finalized():
        MPI.Finalize()
    os._exit(code)


def _resume(args: argparse.Namespace, comm: object) -> int:
    """``pfem2x run --resume DIR``: the scene and options come from DIR."""
    from pfem2x.scene import SceneError  # noqa: PLC0415

    given = [
        opt
        for opt, v in (
            ("SCENE", args.scene),
            ("--set", args.set),
            ("--variant", args.variant),
            ("--out", args.out),
            ("--overwrite", args.overwrite),
        )
        if v
    ]
    if given:
        raise SceneError(f"--resume: takes the scene and folder from DIR, not {', '.join(given)}")
    from pfem2x.runner import Simulation  # noqa: PLC0415

    sim = Simulation.resume(Path(args.resume), comm, quiet=args.quiet)
    return sim.run().exit_code


def _scenes() -> int:
    import tomllib  # noqa: PLC0415

    from pfem2x.scene import builtin_scenes  # noqa: PLC0415

    for name, path in builtin_scenes().items():
        try:
            raw = tomllib.loads(path.read_text())
            desc = raw.get("scene", {}).get("description", "")
            variants = ", ".join(sorted(raw.get("variants", {})))
        except (OSError, tomllib.TOMLDecodeError):
            desc, variants = "(unreadable)", ""
        extra = f"  [variants: {variants}]" if variants else ""
        print(f"{name:24s} {desc}{extra}")
    return 0


if __name__ == "__main__":
    entry()
