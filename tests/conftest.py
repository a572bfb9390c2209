"""Shared test fixtures.

Tests marked ``@pytest.mark.mpi`` are run twice by ``make test``: serially and
under ``mpirun -n 2`` (``pytest -m mpi``). They must be correct on any number
of ranks and write only to per-test temporary folders shared by all ranks.
"""

import os
import pathlib
import shutil
import tempfile

import pytest

from pfem2x.compat import MPI


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
