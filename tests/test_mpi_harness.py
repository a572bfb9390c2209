"""The MPI test harness of ``tests/conftest.py``: a test failing on one rank fails together.

These tests start their own ``mpirun -n 2`` on small generated test files that use
a copy of the project's ``conftest.py``; they run in the serial suite only (not
marked ``mpi``).
"""

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pfem2x.compat import MPI

CONFTEST = Path(__file__).resolve().parent / "conftest.py"
ROOT = Path(__file__).resolve().parent.parent

CHILD_TESTS = """
from pfem2x.compat import MPI

comm = MPI.COMM_WORLD


def test_one_rank_fails_alone():
    assert comm.rank != 1, "rank 1 fails on its own"


def test_after_a_failure():
    comm.Barrier()
    assert comm.allreduce(1) == comm.size


def test_one_rank_fails_then_barrier():
    assert comm.rank != 1, "rank 1 fails while rank 0 goes on to a Barrier"
    comm.Barrier()


def test_never_reached():
    comm.Barrier()
"""


# appended to the copied conftest.py: each rank logs the (agreed) outcome of every phase
LOGGER = """

def pytest_runtest_logreport(report):
    with open(f"outcomes-{MPI.COMM_WORLD.rank}.txt", "a") as f:
        f.write(f"{report.nodeid.split('::')[-1]} {report.when} {report.outcome}\\n")
"""


def _mpirun() -> list[str] | None:
    """The launcher matching this Python's mpi4py (the venv's own first), with root flags."""
    own = Path(sys.executable).parent / "mpirun"
    exe = str(own) if own.exists() else shutil.which("mpirun")
    if exe is None:
        return None
    cmd = [exe]
    version = subprocess.run([exe, "--version"], capture_output=True, text=True).stdout
    if "Open MPI" in version or "OpenRTE" in version:
        cmd.append("--oversubscribe")
        if os.geteuid() == 0:
            cmd.append("--allow-run-as-root")
    return cmd


def _run_child(tmp_path: Path, limit: float) -> tuple[int, str, float]:
    """``mpirun -n 2 pytest`` on the generated tests; (exit code, output, seconds)."""
    launcher = _mpirun()
    if launcher is None:
        pytest.skip("no mpirun on PATH")
    (tmp_path / "conftest.py").write_text(CONFTEST.read_text() + LOGGER)
    (tmp_path / "test_fail_together.py").write_text(CHILD_TESTS)
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("OMPI_", "PMIX_", "PMI_", "HYDRA_", "MPIR_", "PRTE_", "OPAL_"))
    }
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env["PYTHONUNBUFFERED"] = "1"  # MPI_Abort does not flush Python's buffers
    env["PFEM2X_TEST_WARMUP"] = "0"  # no particle kernels here: time the harness alone
    env.pop("PFEM2X_MPI_FAIL_WAIT", None)
    env.pop("PFEM2X_MPI_PASS_WAIT", None)
    cmd = launcher + ["-n", "2", sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"]
    t0 = time.monotonic()
    proc = subprocess.Popen(
        cmd,
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        process_group=0,  # its own group: killed whole on a timeout
    )
    try:
        out, _ = proc.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        pytest.fail(f"the MPI run did not end within {limit:.0f} s:\n{out[-4000:]}")
    return proc.returncode, out, time.monotonic() - t0


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="starts its own mpirun")
def test_failure_on_one_rank_fails_on_all_and_never_hangs(tmp_path):
    code, out, seconds = _run_child(tmp_path, limit=120.0)
    assert seconds < 60.0, f"the MPI run took {seconds:.0f} s:\n{out[-4000:]}"
    assert code != 0, out[-4000:]
    logs = [(tmp_path / f"outcomes-{r}.txt").read_text().splitlines() for r in range(2)]
    # a failure without a following collective: both ranks mark it failed and go on
    for log in logs:
        assert "test_one_rank_fails_alone call failed" in log, (log, out[-4000:])
        assert "test_after_a_failure call passed" in log, (log, out[-4000:])
        assert not any(s.startswith("test_never_reached") for s in log), (log, out[-4000:])
    # a failure while the other rank waits in a collective: the run ends, naming the test
    assert "test_one_rank_fails_then_barrier setup passed" in logs[1], (logs[1], out[-4000:])
    name = "test_fail_together.py::test_one_rank_fails_then_barrier"
    assert f"FAILED {name} on rank 1 (call)" in out, out[-4000:]
    assert "rank 1 fails while rank 0 goes on to a Barrier" in out, out[-4000:]
