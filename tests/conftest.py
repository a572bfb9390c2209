"""Shared test fixtures, and the agreement of the MPI ranks on each test's outcome.

Tests marked ``@pytest.mark.mpi`` are run twice by ``make test``: serially and
under ``mpirun -n 2`` (``pytest -m mpi``). They must be correct on any number
of ranks and write only to per-test temporary folders shared by all ranks.

Under more than one rank, the ranks agree after each phase of each test (set-up,
call, tear-down) on whether it failed anywhere (:func:`pytest_runtest_makereport`):
a test that fails on one rank fails on every rank, and the next test starts on
all ranks together. The agreement is a non-blocking collective on a communicator
of its own, so it never meets a collective of the test. A rank on which the test
failed waits for the others at most ``PFEM2X_MPI_FAIL_WAIT`` seconds (default 20):
if they have not finished the test by then, they are most likely blocked in a
collective that the failed rank will never enter, so it prints
``FAILED <test> on rank <r>`` with the traceback to stderr and aborts the whole
MPI run (``MPI_Abort``). A rank on which the test passed waits at most
``PFEM2X_MPI_PASS_WAIT`` seconds (default 900) before doing the same.

After each test every rank runs Python's garbage collector (:func:`_collect_together`),
so that objects held in reference cycles (a solver and its PETSc objects, a mesh and its
communicator) are freed at the same point on every rank. Left to the automatic collector,
which runs at allocation counts that differ between the ranks, they were freed at
different points, and the DOLFINx 0.11 suite on 2 ranks once died in the next test's mesh
creation after about 100 tests; with the collection here the same tests pass.

Before the tests, rank 0 compiles the particle kernels (or loads them from numba's
cache) and only then do the other ranks load them (:func:`pfem2x.jit.warm_up`);
``PFEM2X_TEST_WARMUP=0`` skips this.
"""

import gc
import os
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np
import pytest

from pfem2x import jit
from pfem2x.compat import MPI

_OUTCOME_COMM = None  # a duplicate of COMM_WORLD for the outcome agreement (size > 1)
_CODE = {"passed": 0, "skipped": 1, "failed": 2}


def pytest_configure(config):
    """Under MPI (collective: every rank runs it): the outcome communicator, and the
    particle kernels compiled by rank 0 before the other ranks load them (two ranks that
    compile the same kernel at once race on numba's cache files)."""
    global _OUTCOME_COMM
    comm = MPI.COMM_WORLD
    if comm.size > 1 and _OUTCOME_COMM is None:
        _OUTCOME_COMM = comm.Dup()
        if os.environ.get("PFEM2X_TEST_WARMUP", "1") != "0":

            def say(msg: str) -> None:
                if comm.rank == 0:
                    print(msg, file=sys.stderr, flush=True)

            jit.warm_up(say, comm=comm)


def _wait_limit(failed: bool) -> float:
    name, default = ("PFEM2X_MPI_FAIL_WAIT", 20.0) if failed else ("PFEM2X_MPI_PASS_WAIT", 900.0)
    try:
        return float(os.environ.get(name, default))
    except ValueError:
        return default


def _abort(item, rep, waited: float) -> None:
    """Name the test on stderr, then end every rank of the MPI run."""
    rank = MPI.COMM_WORLD.rank
    what = "FAILED" if rep.failed else "STUCK"
    lines = [
        "",
        f"{what} {item.nodeid} on rank {rank} ({rep.when}): the other ranks did not finish "
        f"this test within {waited:.0f} s (blocked in a collective?); aborting the MPI run",
    ]
    if rep.failed:
        text = rep.longreprtext
        lines.append(text if len(text) <= 4000 else "...\n" + text[-4000:])
    try:
        sys.stdout.flush()
    finally:
        sys.stderr.write("\n".join(lines) + "\n")
        sys.stderr.flush()
        # the launcher forwards a rank's output through a pipe; MPICH's hydra killed the
        # ranks on MPI_Abort before it had forwarded these lines (the run's output ended
        # without them, now and then): give it a moment
        time.sleep(1.0)
        MPI.COMM_WORLD.Abort(1)


def _agree(item, rep) -> None:
    """Every rank's outcome of this phase to every rank; mark ``rep`` failed if any failed."""
    comm = _OUTCOME_COMM
    mine = np.array([_CODE.get(rep.outcome, 2)], dtype=np.int32)
    codes = np.empty(comm.size, dtype=np.int32)
    req = comm.Iallgather(mine, codes)
    limit = _wait_limit(rep.failed)
    t0 = time.monotonic()
    pause = 1e-4
    while not req.Test():
        waited = time.monotonic() - t0
        if waited > limit:
            _abort(item, rep, waited)
        time.sleep(pause)
        pause = min(2 * pause, 0.02)
    if rep.failed:
        return
    bad = [r for r, c in enumerate(codes) if c == _CODE["failed"]]
    if not bad and rep.when == "setup" and rep.passed and (codes != 0).any():
        # skipped on some ranks only: the others must not run the test body alone
        bad = [r for r, c in enumerate(codes) if c != 0]
        how = "was skipped"
    else:
        how = "failed"
    if bad:
        rep.outcome = "failed"
        rep.longrepr = (
            f"{item.nodeid}: {rep.when} {how} on rank(s) {', '.join(map(str, bad))} "
            f"(its traceback is in that rank's output)"
        )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    """Under MPI, a phase of a test fails on every rank when it fails on any rank."""
    rep = yield
    if _OUTCOME_COMM is not None:
        _agree(item, rep)
    return rep


@pytest.fixture(autouse=True)
def _collect_together():
    """Under MPI, collect the test's garbage on every rank at its end (see the module text)."""
    yield
    if MPI.COMM_WORLD.size > 1:
        gc.collect()


@pytest.fixture
def comm():
    """The world communicator."""
    return MPI.COMM_WORLD


@pytest.fixture
def shared_tmp(request):
    """A temporary folder whose path is the same on all ranks."""
    comm = MPI.COMM_WORLD
    path = tempfile.mkdtemp(prefix="pfem2x-") if comm.rank == 0 else None
    path = pathlib.Path(comm.bcast(path, root=0))
    yield path
    comm.Barrier()
    if comm.rank == 0 and not os.environ.get("PFEM2X_KEEP_TMP"):
        shutil.rmtree(path, ignore_errors=True)


@pytest.fixture
def benchmark_script():
    """``load(name)``: the module ``benchmarks/<name>.py`` (registered while it executes)."""
    import importlib.util

    root = pathlib.Path(__file__).resolve().parent.parent

    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, root / "benchmarks" / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod  # (its dataclasses look their module up)
        try:
            spec.loader.exec_module(mod)
        finally:
            del sys.modules[name]
        return mod

    return load
