"""A small built-in scene end to end through the CLI: every promised output."""

import csv
import json
import subprocess
import sys

import pytest


def run(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "pfem2x", *args], capture_output=True, text=True, timeout=600
    )


def test_scenes_lists_builtins():
    res = run("scenes")
    assert res.returncode == 0
    assert "gaussian-hill" in res.stdout


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "gh"
    res = run(
        "run",
        "gaussian-hill",
        "--variant",
        "small",
        "--out",
        str(out),
        "--set",
        "time.courant=2",
        "--quiet",
    )
    assert res.returncode == 0, res.stderr
    return out, res


def test_summary(small_run):
    out, res = small_run
    s = json.loads((out / "summary.json").read_text())
    for key in (
        "scene",
        "frame",
        "steps",
        "dt",
        "courant_max",
        "wall_seconds",
        "setup_seconds",
        "startup_seconds",
        "status",
        "dolfinx_version",
        "numba_version",
        "mpi_size",
        "metrics",
    ):
        assert key in s, key
    assert s["status"] == "ok"
    assert s["scene"] == "gaussian-hill"
    assert s["mpi_size"] == 1
    # --set time.courant=2 took effect: the run's Courant number is 2 (within the step rounding).
    assert 1.6 < s["courant_max"] <= 2.0 + 1e-9
    assert s["steps"] * s["dt"] == pytest.approx(1.0)
    assert res.stderr.strip() == ""  # --quiet: nothing printed
    # start-up (process start -> first step) holds the set-up and the imports before it
    assert s["startup_seconds"] > s["setup_seconds"] > 0
    # the runner's timers, and their share before the first step (the outputs at t = 0)
    assert {"diagnostics", "output"} <= set(s["timings"])
    assert 0.0 < s["timings_startup"]["output"] <= s["timings"]["output"]


def test_outputs(small_run):
    out, _ = small_run
    assert (out / "fields.xdmf").is_file() and (out / "fields.h5").is_file()
    assert "<Xdmf" in (out / "fields.xdmf").read_text()
    rows = list(csv.DictReader((out / "diagnostics.csv").open()))
    s = json.loads((out / "summary.json").read_text())
    assert len(rows) == s["steps"] + 1
    assert float(rows[0]["max"]) == pytest.approx(1.0, abs=0.05)
    pngs = list(out.glob("*.png"))
    assert pngs and all(p.stat().st_size > 1000 for p in pngs)
    assert (out / "scene.toml").read_text().count("courant = 2") == 1


def test_no_overwrite_without_flag_then_overwrite(small_run):
    out, _ = small_run
    res = run("run", "gaussian-hill", "--variant", "small", "--out", str(out), "--quiet")
    assert res.returncode == 2 and res.stderr.startswith("error:")
    res = run(
        "run", "gaussian-hill", "--variant", "small", "--out", str(out), "--quiet", "--overwrite"
    )
    assert res.returncode == 0, res.stderr


def test_quick_mpi_defaults_without_a_launcher_or_on_one_node():
    """A serial run and an mpirun on one node get Open MPI's quick start; others are kept."""
    from pfem2x.cli import ONE_NODE_MPI, SINGLETON_MPI, quick_mpi_defaults

    env = {"HOME": "/home/u"}
    assert quick_mpi_defaults(env) == SINGLETON_MPI
    assert env == {"HOME": "/home/u", **SINGLETON_MPI}
    one_node = {"OMPI_COMM_WORLD_SIZE": "2", "OMPI_COMM_WORLD_LOCAL_SIZE": "2"}
    assert quick_mpi_defaults(one_node) == ONE_NODE_MPI
    assert one_node["OMPI_MCA_pml"] == "ob1"
    nodes = {"OMPI_COMM_WORLD_SIZE": "8", "OMPI_COMM_WORLD_LOCAL_SIZE": "4"}
    assert quick_mpi_defaults(nodes) == {}
    assert nodes == {"OMPI_COMM_WORLD_SIZE": "8", "OMPI_COMM_WORLD_LOCAL_SIZE": "4"}
    other = {"PMI_RANK": "0", "PMI_SIZE": "2"}  # another launcher (e.g. MPICH's, srun)
    assert quick_mpi_defaults(other) == {} and "OMPI_MCA_pml" not in other
    chosen = {**one_node, "OMPI_MCA_pml": "ucx"}  # mpirun --mca pml ucx
    assert quick_mpi_defaults(chosen) == {} and chosen["OMPI_MCA_pml"] == "ucx"
    mine = {"OMPI_MCA_pml": "ucx"}
    assert quick_mpi_defaults(mine) == {"OMPI_MCA_ess_singleton_isolated": "1"}
    assert mine["OMPI_MCA_pml"] == "ucx"


def test_version_and_check_help():
    import pfem2x

    res = run("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"pfem2x {pfem2x.__version__}"
    helps = {}
    for cmd in ("run", "check"):
        res = run(cmd, "--help")
        assert res.returncode == 0, res.stderr
        helps[cmd] = " ".join(res.stdout.split())
    for text in (
        "scene a scene file (.toml) or a built-in scene name",
        "--set KEY=VALUE override a scene key",
        "--variant VARIANT apply the scene's [variants.NAME]",
    ):
        assert text in helps["run"] and text in helps["check"], text
