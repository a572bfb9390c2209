"""Every demo script runs (small variants): serially, and under `mpirun -n 2` (marker mpi).

Demos are literate scripts executed in-process with ``runpy``, so under
``mpirun -n 2 pytest -m mpi`` all ranks execute them collectively. Under MPI,
rank 0 first runs the same demo serially in a child process, and every run's
``summary.json`` must then match the serial one (:func:`_compare_summaries`).
"""

import json
import math
import os
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from pfem2x.compat import MPI

DEMOS = sorted((Path(__file__).resolve().parent.parent / "demos").glob("*.py"))


@pytest.mark.mpi
@pytest.mark.parametrize("path", DEMOS, ids=[p.stem for p in DEMOS])
def test_demo_runs(path, shared_tmp, monkeypatch):
    monkeypatch.setenv("PFEM2X_DEMO_SMALL", "1")
    monkeypatch.setenv("PFEM2X_DEMO_OUT", str(shared_tmp))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    comm = MPI.COMM_WORLD
    if comm.size > 1:
        err = _serial_reference(path, shared_tmp / "serial") if comm.rank == 0 else None
        err = comm.bcast(err, root=0)
        assert err is None, err
        monkeypatch.setenv("PFEM2X_DEMO_OUT", str(shared_tmp / "mpi"))
    monkeypatch.chdir(shared_tmp)
    runpy.run_path(str(path), run_name="__main__")
    comm.Barrier()
    if comm.size > 1 and comm.rank == 0:
        n = _compare_summaries(shared_tmp / "serial", shared_tmp / "mpi")
        assert n > 0, "the demo wrote no summary.json"


def _serial_reference(path: Path, out: Path) -> str | None:
    """Run demo ``path`` serially in a child process (MPI launcher variables removed)."""
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("OMPI_", "PMIX_", "PMI_", "HYDRA_", "MPIR_", "PRTE_", "OPAL_"))
    }
    env.update(PFEM2X_DEMO_SMALL="1", PFEM2X_DEMO_OUT=str(out), MPLBACKEND="Agg")
    out.mkdir(parents=True, exist_ok=True)
    try:
        r = subprocess.run(
            [sys.executable, str(path)], env=env, cwd=out, capture_output=True, text=True,
            timeout=900,
        )  # fmt: skip
    except subprocess.TimeoutExpired as exc:  # returned, so that every rank fails with it
        return f"serial run timed out after {exc.timeout} s: {(exc.stderr or b'')[-2000:]!r}"
    return None if r.returncode == 0 else f"serial run failed ({r.returncode}): {r.stderr[-2000:]}"


# Serial vs 2 ranks, per metric: |a - b| <= rtol * max(|a|, |b|) + atol.
# Mesh-only frames differ by the iterative solvers (ILU serially, block Jacobi in
# parallel, each converged to its tolerance): measured worst 7e-7 relative on
# Debian's DOLFINx 0.5.2 and 1.7e-4 on the 0.11 wheel (Zalesak Eulerian and
# characteristic runs, l2_error_time_avg over 40 steps; not investigated further).
# Particle frames also differ where population control and neighbour fits see
# another storage order next to the partition boundary: measured worst 4e-4
# relative (integrals) and 3e-3 absolute (the minimum of a unit-amplitude field,
# which is near 0). A "*_change" metric is the difference of two integrals (Zalesak:
# ~510): there 0.034 absolute was measured on the 0.11 wheel (7e-5 of the integral),
# so those get 0.05 absolute in the particle frames.
# The particle frames' largest and RMS cell divergence (``div_max``, ``div_rms_max``)
# are what the discrete projection leaves: its GMRES stops at 5 % of the divergence
# (``flow.divergence_rtol``) on a Krylov path that follows the partition, so they are
# compared to that tolerance (measured: 1.2 % on the 0.11 wheel, the rising-bubble
# demo's PFEM-2 at Courant 2, 0.6759 / 0.6840).
TOLERANCES = {False: (5e-4, 1e-8), True: (2e-3, 5e-3)}
CHANGE_ATOL = 0.05
DIVERGENCE_RTOL = 0.05


def _numbers(d: dict, pre: str = "") -> dict[str, float]:
    out: dict[str, float] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_numbers(v, f"{pre}{k}."))
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            out[pre + k] = float(v)
        elif isinstance(v, list) and v and isinstance(v[0], list):  # [[tau, y], ...]
            for i, row in enumerate(v):
                for j, x in enumerate(row):
                    out[f"{pre}{k}[{i}][{j}]"] = float(x)
    return out


def _compare_summaries(serial: Path, parallel: Path) -> int:
    """Assert every run of ``serial`` has a matching run in ``parallel``; returns the count."""
    files = sorted(serial.rglob("summary.json"))
    for fa in files:
        rel = fa.relative_to(serial)
        fb = parallel / rel
        assert fb.is_file(), f"{rel}: no 2-rank run"
        a, b = json.loads(fa.read_text()), json.loads(fb.read_text())
        assert (a["status"], a["steps"]) == (b["status"], b["steps"]), rel
        assert b["mpi_size"] == 2
        particles = a["frame"] == "lagrangian"
        rtol, atol0 = TOLERANCES[particles]
        ma, mb = _numbers(a["metrics"]), _numbers(b["metrics"])
        assert ma.keys() == mb.keys(), rel
        for k, va in ma.items():
            vb = mb[k]
            atol = CHANGE_ATOL if particles and k.endswith("_change") else atol0
            tol = DIVERGENCE_RTOL if particles and k.startswith("div_") else rtol
            if math.isnan(va):
                assert math.isnan(vb), (rel, k)
                continue
            assert abs(va - vb) <= tol * max(abs(va), abs(vb)) + atol, (str(rel), k, va, vb)
    return len(files)


def test_demos_are_jupytext_percent_scripts():
    assert DEMOS, "no demos found"
    for p in DEMOS:
        text = p.read_text()
        assert "format_name: percent" in text and "# %%" in text, p.name


def test_demo_converts_to_notebook(tmp_path):
    jupytext = pytest.importorskip("jupytext")
    nb = jupytext.read(DEMOS[0])
    assert any(c.cell_type == "markdown" for c in nb.cells)
    assert any(c.cell_type == "code" for c in nb.cells)
    os.makedirs(tmp_path, exist_ok=True)
    jupytext.write(nb, tmp_path / "demo.ipynb")
    assert (tmp_path / "demo.ipynb").stat().st_size > 0


def test_explorer_runs_as_a_notebook(tmp_path, monkeypatch):
    """The interface explorer converts to a notebook and executes headless."""
    jupytext = pytest.importorskip("jupytext")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    monkeypatch.setenv("PFEM2X_DEMO_SMALL", "1")
    monkeypatch.setenv("PFEM2X_DEMO_OUT", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    path = next(p for p in DEMOS if p.stem == "explore_interfaces")
    nb = jupytext.read(path)
    nb.metadata["kernelspec"] = {
        "name": "python3",
        "display_name": "Python 3",
        "language": "python",
    }
    client = nbclient.NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}
    )
    client.execute()
    outputs = "".join(
        o.get("text", "") for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
    )
    assert "status ok" in outputs
    assert (tmp_path / "explore" / "tips.png").stat().st_size > 1000
