"""The particle kernels' numba compilation: done at set-up when the cache is cold, announced.

The kernels of :mod:`pfem2x.particles._kernels` are compiled by numba on first
use (under a minute with numba 0.68 on a 2-core virtual machine; numba 0.56 took
about 8 minutes) and cached on disk next to the source
(``pfem2x/particles/__pycache__``, or under ``NUMBA_CACHE_DIR``); later runs
load them from there. On a cold cache :func:`warm_up` compiles every kernel a
scene may use by running the particle layer once on a tiny mesh, and says so
first. ``make setup`` runs it (``python -m pfem2x.jit``, which also byte-compiles the
package's modules: :func:`compile_bytecode`), so a first ``pfem2x run`` after
installing starts at once; the runner calls it during set-up and
reports the seconds it took as ``compile_seconds``. On a warm cache it does
nothing: each kernel loads from the cache when a run first calls it, so a run
loads only the specialisations it uses (a Rayleigh–Taylor run on one core starts
about 0.25 s sooner than after loading all of them).

After the warm-up, ``python -m pfem2x.jit`` also compiles the same specialisations
ahead of time (:mod:`pfem2x.aot`), so that runs need neither numba nor its cache.

The cache is cold when the marker :data:`MARKER` that a completed warm-up leaves
next to the cache files is missing or older than a kernel source or this module
(:data:`SOURCES`), when fewer cache index files are there than the warm-up left, or
when the warm-up ran with another numba version (numba does not load code cached by
another version). Should the check be wrong, the first kernel numba compiles during
the run is announced (a numba event listener).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.machinery
import json
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from pfem2x import aot
from pfem2x.aot import JIT_SOURCES, KERNELS, TAG, cache_dir, numba_version

#: What a run prints (rank 0, not with ``--quiet``) while the kernels compile.
MESSAGE = "compiling particle kernels (first run after install or a kernel change)..."

#: Every module of numba kernels that :func:`exercise_particles` compiles, and this
#: module (which kernels the warm-up calls, with which argument types): a change to any
#: of them makes the cache cold.
SOURCES = JIT_SOURCES
_TAG = TAG
#: Left next to the cache files by a completed warm-up: the number of index files and
#: the numba version.
MARKER = f"_kernels.warm.{_TAG}"


def _index_files(folder: Path) -> list[Path]:
    """numba's index files of the current ``_kernels.py`` (those of earlier versions stay)."""
    if not folder.is_dir():
        return []
    src = KERNELS.stat().st_mtime
    return [p for p in folder.glob(f"_kernels.*.{_TAG}.nbi") if p.stat().st_mtime >= src]


def is_cold() -> bool:
    """Whether :func:`warm_up` will compile (cheap: file times only).

    Returns
    -------
    bool
        True when no completed warm-up of the current ``_kernels.py`` left its
        marker, or cache index files have gone since.
    """
    folder = cache_dir()
    marker = folder / MARKER
    try:
        src = max(p.stat().st_mtime for p in SOURCES)
        if marker.stat().st_mtime < src:
            return True
        fields = marker.read_text().split()
        expected = int(fields[0]) if fields else 0
    except (OSError, ValueError):
        return True
    if len(fields) < 2 or fields[1] != numba_version():
        return True
    return len(_index_files(folder)) < expected


def _mark_warm() -> None:
    folder = cache_dir()
    try:
        (folder / MARKER).write_text(f"{len(_index_files(folder))} {numba_version()}\n")
    except OSError:  # a read-only install: numba caches elsewhere or not at all
        pass


def _import_kernel_modules() -> None:
    """Import the three kernel modules (:data:`pfem2x.aot.KERNEL_MODULES`)."""
    import pfem2x.particles._kernels  # noqa: F401, PLC0415
    import pfem2x.physics.flow._kernels  # noqa: F401, PLC0415
    import pfem2x.physics.flow._load_kernels  # noqa: F401, PLC0415


def _through_numba() -> None:
    """Every kernel through numba's JIT in this process: numba's cache is what the
    exercise fills, also where a compiled module would serve (:func:`pfem2x.aot.use_numba`)."""
    _import_kernel_modules()  # (all of them before use_numba)
    aot.use_numba()


def exercise_particles() -> None:
    """Run every particle operation once on a tiny mesh of this process alone.

    Calls the kernels with the argument types the transport and flow solvers
    pass (scalar and vector fields, P1 and callable velocities, the X-IVAS
    blend, sources along the path, both projections, population control), so
    that numba compiles (or loads from its cache) each specialisation a scene
    needs. Collective over ``MPI.COMM_SELF`` only: any rank may call it at any
    time.
    """
    # imported here so that the cache check (``make setup``) stays cheap
    from pfem2x import compat  # noqa: PLC0415
    from pfem2x import particles as P  # noqa: PLC0415
    from pfem2x.compat import MPI, dolfinx  # noqa: PLC0415
    from pfem2x.mesh import build_mesh  # noqa: PLC0415

    _through_numba()
    d = build_mesh(MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [3, 3])
    g = d.gdim
    V = compat.function_space(d.mesh, 1)
    W = compat.function_space(d.mesh, 1, shape=(g,))
    T, T_hat, dT = (dolfinx.fem.Function(V) for _ in range(3))
    u, u_old, u_hat = (dolfinx.fem.Function(W) for _ in range(3))
    xv = V.tabulate_dof_coordinates()[:, :g]
    T.x.array[:] = np.exp(-((xv[:, 0] - 0.5) ** 2 + (xv[:, 1] - 0.5) ** 2))
    dT.x.array[:] = 1e-3
    xw = W.tabulate_dof_coordinates()[:, :g]
    uw = np.column_stack([0.5 - xw[:, 1], xw[:, 0] - 0.5]) * 0.1
    u.x.array[:] = uw.reshape(-1)
    u_old.x.array[:] = u.x.array

    cloud = P.Cloud(d, {"T": (), "u": (g,), "phase": (), "_mom": (g + 1,)})
    P.seed_cells(cloud, 6, seed=1)
    P.interpolate(cloud, "T", T)
    P.interpolate(cloud, "u", u)
    cloud.field("phase")[:] = cloud.x[:, 1] < 0.5
    P.assign_ids(cloud)
    cloud.check()

    def vel(x: np.ndarray, s: Any) -> np.ndarray:
        return 0.1 * np.column_stack([0.5 - x[:, 1], x[:, 0] - 0.5])

    def source(x: np.ndarray, s: Any) -> np.ndarray:
        return np.ones(len(x))

    dt = 0.2
    P.advect(cloud, u, dt, courant=0.5, gradient_courant=0.1)
    P.advect(cloud, u_old, dt, velocity_next=u, theta=0.5, courant=0.5, gradient_courant=0.1)
    P.advect(cloud, u.x.array.reshape(-1, g).copy(), dt)
    P.advect(cloud, vel, dt, substeps=2, source=source, source_field="T", source_scale=0.5)
    P.advect(cloud, u, dt, source=T, source_field="T")
    for method in ("linear", "average"):
        P.project(cloud, "T", T_hat, method=method, empty="neighbours")
        P.project(cloud, "u", u_hat, method=method, empty="neighbours")
    P.project(cloud, "phase", T_hat, method="average", empty="keep")
    together = [("T", T, "linear"), ("u", u_hat, "average"), ("phase", T_hat, "average")]
    P.project_fields(cloud, together[:2], empty="neighbours")  # (one average field: its own
    P.project_fields(cloud, together, empty="neighbours")  # specialisation, as two)
    mom = np.zeros((len(xv), g + 1))
    P.project(cloud, "_mom", mom, method="average", empty="neighbours")
    P.evaluate(cloud, T)
    P.evaluate(cloud, u)
    P.add_increment(cloud, "T", dT)
    P.add_increment(cloud, "u", u)
    P.relocate(cloud)
    P.locate_points(cloud.pmesh, cloud.x[:4].copy())
    P.rebalance(cloud, 4, 8, seed=2, fallback={"T": T})
    P.rebalance(cloud, 10, 12, seed=3, fallback={"u": u, "phase": T})
    cloud.remove(cloud.x[:, 0] > 0.5)  # empty cells: nodes that only neighbours fill
    for method in ("linear", "average"):
        P.project(cloud, "T", T_hat, method=method, empty="neighbours")
        P.project(cloud, "u", u_hat, method=method, empty="neighbours")
    P.project(cloud, "_mom", mom, method="average", empty="neighbours")
    drop = np.zeros(cloud.n, dtype=bool)
    drop[::3] = True
    cloud.remove(drop)
    P.rebalance(cloud, 6, 0, seed=4, fallback={"T": T, "u": u})
    _exercise_flow_particles(cloud)
    _exercise_interface(xv[:4], not compat.dofmap_array(V).flags.writeable)


def _exercise_flow_particles(cloud: Any) -> None:
    """The PFEM-2 frame's own particle kernels: the first pass's share of each cell's
    particles (``flow.predictor_particles``) and the cellwise operators' structure."""
    from pfem2x.particles import _kernels as K  # noqa: PLC0415

    K.share_drop(cloud.cells, cloud.pmesh.n_cells, 0.5)
    one = np.zeros((1, 3), dtype=np.int64)
    K.entry_structure(one, one, np.zeros((1, 3, 3)), 1)


def _exercise_interface(points: Any, readonly_dofs: bool) -> None:
    """The flow's compiled kernels once: interface geometry (balanced gravity, cut-cell
    densities, the curvature's circle fits, the interface files' polylines), the loads of
    :mod:`pfem2x.physics.flow.loads` and the per-cell velocity measures of the
    diagnostics. ``readonly_dofs``: the kernels take DOLFINx's dofmaps as they come, which
    DOLFINx 0.11 gives as read-only arrays (numba compiles a kernel for each kind)."""
    from pfem2x.io import chain_segments  # noqa: PLC0415
    from pfem2x.physics.flow._kernels import (  # noqa: PLC0415
        cell_velocity_kernel,
        mark_mixed_cells,
        particle_fraction_kernel,
    )
    from pfem2x.physics.flow._load_kernels import (  # noqa: PLC0415
        force_load_kernel,
        pressure_load_kernel,
    )
    from pfem2x.physics.flow.balanced import closest_points  # noqa: PLC0415
    from pfem2x.physics.flow.curvature import (  # noqa: PLC0415
        circle_misfit,
        closest_pairs_within,
        distance_curvature,
    )
    from pfem2x.physics.flow.interface import (  # noqa: PLC0415
        cut_segments,
        positive_fraction,
        segment_distance,
    )

    seg = np.array([[[0.0, 0.5], [1.0, 0.5]]])
    closest_points(points, seg)
    # the curvature's fits on a circle (surface tension)
    th = np.linspace(0.0, 2.0 * np.pi, 25)
    ring = 0.5 + 0.3 * np.column_stack([np.cos(th), np.sin(th)])
    segs = np.stack([ring[:-1], ring[1:]], axis=1)
    normals = segs.mean(axis=1) - 0.5
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 11), np.linspace(0, 1, 11)), -1).reshape(-1, 2)
    dist = 0.3 - np.linalg.norm(grid - 0.5, axis=1)
    _, _, coef = distance_curvature(segs, normals, grid, dist, 0.25)
    circle_misfit(segs, normals, coef, ring, 0.25)
    closest_pairs_within(grid, segs, 0.25, 1e-12)
    chain_segments(segs)
    positive_fraction(np.array([[1.0, -1.0, 0.5]]))
    segment_distance(points, seg, cap=0.25)
    dofs = np.array([[0, 1, 2]], dtype=np.int32)
    dofs.flags.writeable = not readonly_dofs
    cell_velocity_kernel(np.zeros((3, 2)), dofs, np.zeros((1, 3, 2)))
    cut_segments(np.array([[1.0, -1.0, 0.5]]), np.zeros((1, 3, 2)))
    mark_mixed_cells(np.array([1.0, -1.0, 0.5]), dofs, np.zeros(3))
    particle_fraction_kernel(np.zeros(2, dtype=np.int32), np.ones(2), 1, np.zeros(3), dofs)
    one, g = np.ones(1), np.zeros(2)
    force_load_kernel(
        np.zeros((1, 3, 2)), one, dofs, dofs, one, g, np.zeros(3), np.zeros(3), np.zeros(6)
    )
    pressure_load_kernel(
        np.zeros((1, 3, 2)),
        one,
        dofs,
        dofs,
        one,
        g,
        np.zeros(3),
        np.zeros(3),
        np.zeros(6),
        np.zeros(3),
    )


class _CompileNotice:
    """Says :data:`MESSAGE` once, at the first kernel numba compiles instead of loading.

    A numba event listener (``numba:compile`` fires on a cache miss only), registered
    once per process; :func:`warm_up` re-arms it with its own ``say``.
    """

    _listener: Any = None

    @classmethod
    def arm(cls, say: Callable[[str], Any] | None) -> None:
        """The next compile calls ``say`` (``None``: nothing)."""
        if cls._listener is None and say is None:
            return
        from numba.core import event  # noqa: PLC0415

        if cls._listener is None:

            class Listener(event.Listener):
                say: Callable[[str], Any] | None = None

                def on_start(self, ev: Any) -> None:
                    say, self.say = self.say, None
                    if say is not None:
                        say(MESSAGE)

                def on_end(self, ev: Any) -> None:
                    pass

            cls._listener = Listener()
            event.register("numba:compile", cls._listener)
        cls._listener.say = say


def warm_up(say: Callable[[str], Any] | None = None, comm: Any = None) -> float:
    """Compile every particle kernel when the cache is cold, and announce it.

    On a warm cache (rank 0's :func:`is_cold` false) nothing is compiled or loaded
    here: each kernel loads from the cache when a run first calls it, and ``say``
    is still called once should numba compile one after all (the check was wrong).

    Parameters
    ----------
    say:
        Called with :data:`MESSAGE` before compiling; ``None`` keeps quiet. Pass a
        function that prints on rank 0 only.
    comm:
        An MPI communicator (collective then): on a cold cache rank 0 compiles
        first and the other ranks load its cache files afterwards. Several
        processes that compile the same kernels at once write the same cache
        files, and numba does not lock them (a process may load another's code
        for its own signature). ``None``: this process alone.

    Returns
    -------
    float
        Wall seconds spent compiling the kernels (on this rank, waiting for rank 0
        included; on a warm cache the check's).
    """
    t0 = time.perf_counter()
    single = comm is None or comm.size == 1
    cold = is_cold() if single else comm.bcast(is_cold() if comm.rank == 0 else None, root=0)
    _CompileNotice.arm(say if not cold else None)
    if not cold:
        return time.perf_counter() - t0
    if single:
        if say is not None:
            say(MESSAGE)
        exercise_particles()
        _mark_warm()
        return time.perf_counter() - t0
    failed: BaseException | None = None
    if comm.rank == 0:
        try:
            if say is not None:
                say(MESSAGE)
            exercise_particles()
            _mark_warm()
        except Exception as exc:  # re-raised on every rank below, after the collective
            failed = exc
    from pfem2x.compat import MPI  # noqa: PLC0415

    if comm.allreduce(failed is not None, op=MPI.LOR):
        raise RuntimeError(f"compiling the particle kernels failed on rank 0: {failed}") from failed
    if comm.rank != 0:
        exercise_particles()
    return time.perf_counter() - t0


def _aot_spec(t: Any) -> list:
    """A numba argument type as a manifest entry (``ValueError``: not exportable)."""
    from numba.core import types  # noqa: PLC0415
    from numba.np.numpy_support import as_dtype  # noqa: PLC0415

    if isinstance(t, types.Array):
        return ["array", as_dtype(t.dtype).str, t.ndim, t.layout, not t.mutable]
    if isinstance(t, types.BaseNamedTuple):
        return ["tuple", t.instance_class.__name__, [_aot_spec(s) for s in t.types]]
    if isinstance(t, types.BaseTuple):
        return ["tuple", None, [_aot_spec(s) for s in t.types]]
    if isinstance(t, types.Boolean):
        return ["scalar", "bool"]
    if isinstance(t, types.Integer | types.Float):
        return ["scalar", str(as_dtype(t))]
    raise ValueError(f"argument type {t} is not exported")


@contextlib.contextmanager
def _numpy_error_model() -> Iterator[None]:
    """numba's ahead-of-time compiler with the kernels' ``error_model="numpy"``.

    Its flags default to Python's error model (a division by zero raises); the
    kernels are JIT-compiled with numpy's (it gives inf or nan).
    """
    from numba.pycc import compiler  # noqa: PLC0415

    base = compiler.Flags

    class NumpyErrors(base):  # type: ignore[misc, valid-type]
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.error_model = "numpy"

    compiler.Flags = NumpyErrors
    try:
        yield
    finally:
        compiler.Flags = base


def _aot_signatures(path: Path) -> int:
    """Exercise the kernels under numba's JIT and pickle what they ran to ``path``.

    ``{qualified name: [(argument types, return type), ...]}``; returns their number.
    """
    import pickle  # noqa: PLC0415

    from numba.core.registry import CPUDispatcher  # noqa: PLC0415

    exercise_particles()
    sigs: dict[str, list] = {}
    for modname in aot.KERNEL_MODULES:
        for func in vars(sys.modules[modname]).values():
            if isinstance(func, CPUDispatcher) and func.__module__ == modname:
                for sig in func.signatures:
                    ret = func.overloads[sig].signature.return_type
                    sigs.setdefault(f"{modname}.{func.py_func.__qualname__}", []).append((sig, ret))
    path.write_bytes(pickle.dumps(sigs))
    return sum(len(v) for v in sigs.values())


def _aot_compile(folder: Path, path: Path) -> int:
    """Compile the specialisations pickled at ``path`` (:func:`_aot_signatures`) into the
    module and its manifest in ``folder``; returns their number.

    A process of its own: numba's ahead-of-time compiler can fail to type a kernel
    that numba's JIT compiled earlier in the same process.
    """
    import pickle  # noqa: PLC0415

    from numba.pycc import CC  # noqa: PLC0415

    sigs = pickle.loads(path.read_bytes())
    digest = aot.source_hash()
    cc = CC(aot.NAME)
    cc.output_dir = str(folder)
    cc.output_file = f"{aot.NAME}.{digest[:12]}{importlib.machinery.EXTENSION_SUFFIXES[0]}"
    cc.target_cpu = "host"  # (numba's JIT compiles for this machine's CPU too)
    kernels: dict[str, list] = {}
    n = 0
    for qual, variants in sigs.items():
        modname, name = qual.rsplit(".", 1)
        func = getattr(sys.modules[modname], name).py_func
        for sig, ret in variants:
            try:
                specs = [_aot_spec(t) for t in sig]
            except ValueError:  # (an argument the module cannot take: numba's JIT serves it)
                continue
            export = f"k{n}"
            cc.export(export, ret(*sig))(func)
            kernels.setdefault(qual, []).append([export, specs])
            n += 1
    with _numpy_error_model():
        cc.compile()
    manifest = {"file": cc.output_file, "hash": digest, "kernels": kernels}
    tmp = folder / f"{aot.MANIFEST}.{os.getpid()}"
    tmp.write_text(json.dumps(manifest))
    os.replace(tmp, folder / aot.MANIFEST)
    for old in folder.glob(f"{aot.NAME}.*{importlib.machinery.EXTENSION_SUFFIXES[0]}"):
        if old.name != cc.output_file:  # (an earlier build for this Python)
            old.unlink(missing_ok=True)
    return n


def build_ahead_of_time() -> tuple[bool, str]:
    """Compile the kernels ahead of time (two processes under numba's JIT).

    The first runs the warm-up's exercise (:func:`exercise_particles`)
    and records each kernel's specialisations; the second compiles them.

    Returns
    -------
    tuple[bool, str]
        Whether the module was built, and what to tell the user: the seconds and
        the folder, or why not (runs then take numba's JIT, as before).
    """
    import tempfile  # noqa: PLC0415

    t0 = time.perf_counter()
    env = {**os.environ, aot.ENV: "numba"}
    with tempfile.TemporaryDirectory() as tmp:
        sigs = str(Path(tmp) / "signatures.pickle")
        for step in ("--aot-signatures", "--aot-compile"):
            cmd = [sys.executable, "-m", "pfem2x.jit", step, sigs]
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            if r.returncode != 0:
                lines = r.stderr.strip().splitlines() or ["(no message)"]
                why = next((ln for ln in reversed(lines) if "Error" in ln), lines[-1])
                return False, f"kernels not compiled ahead of time (numba's JIT serves): {why}"
    seconds = time.perf_counter() - t0
    return True, f"kernels compiled ahead of time in {seconds:.0f} s ({cache_dir()})"


def _aot_step(signatures: str | None, compile_from: str | None) -> int:
    """One step of :func:`build_ahead_of_time` (its own process, numba's JIT)."""
    if os.environ.get(aot.ENV) != "numba":
        print(f"error: {aot.ENV}=numba must be set (build_ahead_of_time sets it)", file=sys.stderr)
        return 2
    if signatures:
        print(f"{_aot_signatures(Path(signatures))} kernel specialisations recorded")
        return 0
    _import_kernel_modules()  # (under numba's JIT: their source functions)
    folder = cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    n = _aot_compile(folder, Path(str(compile_from)))
    print(f"{n} kernel specialisations compiled: {folder / aot.MANIFEST}")
    return 0


def compile_bytecode(root: Path | None = None) -> bool:
    """Byte-compile the package's modules whose ``.pyc`` is missing or stale.

    Python writes a module's ``.pyc`` when it first imports it, unless it may not
    (``PYTHONDONTWRITEBYTECODE``, a read-only folder): then every process compiles
    every module it imports anew, about 0.2 s of each run's start here. Written
    explicitly, the files are read whatever that setting (a module changed since is
    compiled in memory, as Python does). Up to date, this is a check of the files'
    times.

    Parameters
    ----------
    root
        The folder to compile (default: the package's).

    Returns
    -------
    bool
        Whether every module compiled (a folder that cannot be written: ``False``).
    """
    import compileall  # noqa: PLC0415

    folder = root or Path(__file__).resolve().parent
    return bool(compileall.compile_dir(str(folder), quiet=2))


def main(argv: list[str] | None = None) -> int:
    """``python -m pfem2x.jit``: warm the kernel cache and byte-compile the package
    (``make setup`` runs it)."""
    ap = argparse.ArgumentParser(prog="python -m pfem2x.jit", description=__doc__.split("\n")[0])
    ap.add_argument(
        "--check", action="store_true", help="only say whether the cache is cold (exit 1)"
    )
    ap.add_argument(
        "--if-cold", action="store_true", help="warm up only when the cache is cold (else silent)"
    )
    ap.add_argument("--aot-signatures", metavar="FILE", help=argparse.SUPPRESS)
    ap.add_argument("--aot-compile", metavar="FILE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.aot_signatures or args.aot_compile:  # (the steps of build_ahead_of_time)
        return _aot_step(args.aot_signatures, args.aot_compile)
    cold, current = is_cold(), aot.is_current()
    if args.check:
        print(f"pfem2x: particle kernel cache {'cold' if cold else 'warm'} ({cache_dir()})")
        print(f"pfem2x: kernels compiled ahead of time: {'current' if current else 'no'}")
        return 1 if cold or not current else 0
    compile_bytecode()
    if (
        not cold and not args.if_cold
    ):  # (runs load each kernel from the cache when they first call it)
        print(f"pfem2x: particle kernel cache warm, nothing to compile ({cache_dir()})")
    if cold:

        def say(msg: str) -> None:
            print(msg, file=sys.stderr, flush=True)

        seconds = warm_up(say)
        print(f"pfem2x: particle kernels compiled in {seconds:.1f} s ({cache_dir()})")
    if not current:
        print("pfem2x: compiling the kernels ahead of time...", file=sys.stderr, flush=True)
        print(f"pfem2x: {build_ahead_of_time()[1]}")
    elif not args.if_cold:
        print("pfem2x: kernels compiled ahead of time: current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
