"""Every demo script runs (small variants): serially, and under `mpirun -n 2` (marker mpi).

Demos are literate scripts executed in-process with ``runpy``, so under
``mpirun -n 2 pytest -m mpi`` all ranks execute them collectively.
"""

import os
import runpy
from pathlib import Path

import pytest

DEMOS = sorted((Path(__file__).resolve().parent.parent / "demos").glob("*.py"))


@pytest.mark.mpi
@pytest.mark.parametrize("path", DEMOS, ids=[p.stem for p in DEMOS])
def test_demo_runs(path, shared_tmp, monkeypatch):
    monkeypatch.setenv("PFEM2X_DEMO_SMALL", "1")
    monkeypatch.setenv("PFEM2X_DEMO_OUT", str(shared_tmp))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.chdir(shared_tmp)
    runpy.run_path(str(path), run_name="__main__")


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
