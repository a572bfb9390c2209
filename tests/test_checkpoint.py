"""Checkpoint / restart: resumed runs continue the uninterrupted ones; signals; torn checkpoints."""

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from pfem2x import cli, compat
from pfem2x.compat import MPI
from pfem2x.runner import Simulation, find_checkpoint
from pfem2x.scene import load_scene, validate

TRANSPORT = {
    "scene": {"name": "ck"},
    "mesh": {"kind": "rectangle", "bounds": [[-1, -1], [1, 1]], "cells": [10, 10]},
    "effects": {"advection": True, "diffusion": True},
    "transport": {
        "velocity": ["-y", "x"],
        "kappa": 0.002,
        "initial": "exp(-20*((x-0.4)**2 + y**2))",
        "boundary_value": 0,
    },
    "time": {"t_end": 1.0, "dt": 0.05},
    "method": {"min_particles_per_cell": 4, "max_particles_per_cell": 16},
    "output": {"png": False, "every": 0.25},
}


def transport(frame: str, **time_over):
    raw = json.loads(json.dumps(TRANSPORT))
    raw["method"]["frame"] = frame
    raw["time"].update(time_over)
    return validate(raw)


def rayleigh_taylor():
    return load_scene(
        "rayleigh-taylor", ["mesh.cells=[8, 32]", "time.t_end=0.6", "output.png=false"], "small"
    )


def interrupted_run(scene, out, at_step: int) -> Simulation:
    """Run until ``at_step`` and SIGTERM ourselves (rank 0 only: the flag is reduced)."""
    sim = Simulation(scene, out, quiet=True)

    def hook(s, step, t):
        if step == at_step and MPI.COMM_WORLD.rank == 0:
            os.kill(os.getpid(), signal.SIGTERM)

    sim.on_step = hook
    res = sim.run()
    assert res.status == "interrupted" and res.exit_code == 143, res.summary["message"]
    assert res.summary["steps"] == at_step
    assert "SIGTERM" in res.summary["message"] and "--resume" in res.summary["message"]
    return sim


def rows(path):
    with open(path, newline="") as f:
        r = list(csv.reader(f))
    i = r[0].index("wall_step")
    return [x[:i] + x[i + 1 :] for x in r]


def state_arrays(sim):
    ck = sim.solver.checkpoint()
    return {k: v for k, v in ck.items() if k.startswith(("function.", "cloud."))}


CASES = {
    "transport-eulerian": (lambda: transport("eulerian"), 7),
    "transport-lagrangian": (lambda: transport("lagrangian"), 9),
    "rayleigh-taylor-lagrangian": (rayleigh_taylor, 3),
}


@pytest.mark.mpi
@pytest.mark.parametrize("case", sorted(CASES))
def test_resume_matches_uninterrupted(shared_tmp, case):
    make, at = CASES[case]
    comm = MPI.COMM_WORLD
    full = Simulation(make(), shared_tmp / "full", quiet=True)
    ra = full.run()
    interrupted_run(make(), shared_tmp / "run", at)
    meta = shared_tmp / "run" / "checkpoint" / "meta.json"
    assert comm.bcast(meta.is_file() if comm.rank == 0 else None, root=0)  # fail on all ranks
    resumed = Simulation.resume(shared_tmp / "run", quiet=True)
    rb = resumed.run()
    assert rb.status == "ok" and rb.summary["resumed_at_step"] == at
    assert rb.summary["steps"] == ra.summary["steps"]
    if comm.size == 1 and not compat.NEW_API:  # Debian's DOLFINx 0.5.2: bit-identical
        a, b = state_arrays(full), state_arrays(resumed)
        assert a.keys() == b.keys()
        for k in a:
            assert np.array_equal(a[k], b[k]), k
        assert rb.summary["metrics"] == ra.summary["metrics"]
        assert rows(shared_tmp / "run" / "diagnostics.csv") == rows(
            shared_tmp / "full" / "diagnostics.csv"
        )
    elif comm.size == 1:
        # DOLFINx 0.11 (PyPI wheel): in some processes the resumed transport-eulerian run
        # differs from the uninterrupted one by up to 2e-15 (79 of 121 nodal values, seen
        # only when another case ran first in the process; two uninterrupted runs never
        # differed). Suspected: the wheel's PETSc vector kernels depend on memory alignment.
        # Round-off, not bit identity, is asserted there. The pressure of a closed box is
        # defined up to a constant, and once in CI the resumed rayleigh-taylor-lagrangian
        # run's p and dp differed from the uninterrupted run's by a constant 1.3e-3 (2.6e-4
        # of max |p|; u within round-off): the singular pressure solve's constant component
        # follows the round-off. The pressures are compared without that constant there.
        a, b = state_arrays(full), state_arrays(resumed)
        assert a.keys() == b.keys()
        for k in a:
            scale = max(float(np.abs(a[k]).max(initial=0.0)), 1e-300)
            diff = a[k] - b[k]
            if k in ("function.p", "function.dp"):
                diff = diff - diff.mean()
            assert np.abs(diff).max(initial=0.0) <= 1e-13 * scale, k
    else:
        # The built-in meshes are partitioned deterministically (partition.block_partitioner),
        # so the resumed run continues on the same partition: round-off only.
        cells_a = full.solver.checkpoint()["mesh.cells"]
        cells_b = resumed.solver.checkpoint()["mesh.cells"]
        assert comm.allreduce(int(np.array_equal(cells_a, cells_b)), op=MPI.MIN)
        worst = 0.0
        for ha, hb in zip(ra.history, rb.history, strict=True):
            for k, v in ha.items():
                worst = max(worst, abs(hb[k] - v) / max(abs(v), 1e-7))
        assert worst < 1e-9, worst
    if comm.rank == 0:
        assert (shared_tmp / "run" / f"fields_resumed_{at}.xdmf").is_file()
        n = len(rows(shared_tmp / "run" / "diagnostics.csv"))
        assert n == ra.summary["steps"] + 2  # header + steps 0..N, no duplicated rows


def test_torn_checkpoint_does_not_break_resume(shared_tmp):
    make = CASES["transport-lagrangian"][0]
    ra = Simulation(make(), shared_tmp / "full", quiet=True).run()
    out = shared_tmp / "run"
    interrupted_run(make(), out, 6)
    # a kill while writing the next checkpoint: a partial temp folder ...
    tmp = out / ".checkpoint.tmp"
    tmp.mkdir()
    (tmp / "rank0.npz").write_bytes(b"PK\x03\x04 partial")
    # ... and one between the two renames: only the previous checkpoint, as .checkpoint.old,
    # plus a half-written checkpoint/ without meta.json
    os.replace(out / "checkpoint", out / ".checkpoint.old")
    (out / "checkpoint").mkdir()
    (out / "checkpoint" / "rank0.npz").write_bytes(b"junk")
    found = find_checkpoint(out)
    assert found is not None and found[0].name == ".checkpoint.old" and found[1]["step"] == 6
    rb = Simulation.resume(out, quiet=True).run()
    assert rb.status == "ok"
    assert rb.summary["metrics"] == ra.summary["metrics"]
    # the next checkpoint write cleans up
    sim = Simulation.resume(out, quiet=True)
    sim.run()


def test_resume_errors(shared_tmp, capsys):
    out = shared_tmp / "run"
    Simulation(transport("eulerian", t_end=0.2), out, quiet=True).run()
    assert cli.main(["run", "--resume", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "no complete checkpoint" in err
    assert cli.main(["run", "--resume", str(shared_tmp / "nothing")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    # another number of ranks
    interrupted_run(transport("eulerian"), shared_tmp / "r2", 3)
    ck = shared_tmp / "r2" / "checkpoint"
    meta = json.loads((ck / "meta.json").read_text())
    meta["mpi_size"] = 2
    (ck / "meta.json").write_text(json.dumps(meta))
    shutil.copy(ck / "rank0.npz", ck / "rank1.npz")
    assert cli.main(["run", "--resume", str(shared_tmp / "r2")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "2 MPI rank(s)" in err and err.count("\n") == 1
    # a scene with --resume
    assert cli.main(["run", "zalesak", "--resume", str(shared_tmp / "r2")]) == 2
    assert capsys.readouterr().err.startswith("error: --resume")


def test_damaged_checkpoint_file_is_an_error_line(shared_tmp, capsys):
    """A truncated ``rank0.npz``: one error: line naming it, exit 2, every file kept."""
    out = shared_tmp / "run"
    interrupted_run(transport("eulerian"), out, 3)
    npz = out / "checkpoint" / "rank0.npz"
    if MPI.COMM_WORLD.rank == 0:
        npz.write_bytes(npz.read_bytes()[:200])
    MPI.COMM_WORLD.Barrier()
    files = {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    capsys.readouterr()
    assert cli.main(["run", "--resume", str(out)]) == 2
    err = capsys.readouterr().err
    if MPI.COMM_WORLD.rank == 0:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: "), err
        assert str(npz) in lines[0] and "Traceback" not in err
    assert {p: p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()} == files


# -- real processes: SIGKILL / SIGTERM -------------------------------------------------
LONG = {
    **TRANSPORT,
    "mesh": {"kind": "rectangle", "bounds": [[-1, -1], [1, 1]], "cells": [8, 8]},
    "effects": {"advection": True},
    "transport": {"velocity": ["-y", "x"], "initial": "exp(-20*((x-0.4)**2 + y**2))"},
    "time": {"t_end": 6.0, "dt": 0.005},
    "method": {"frame": "lagrangian", "min_particles_per_cell": 4, "max_particles_per_cell": 16},
    "output": {"png": False, "every": 1.0, "checkpoint_every": 20},
}


def _write_scene(path):
    from pfem2x.scene import dump_toml

    path.write_text(dump_toml(LONG))
    return path


def _pfem2x(*args):
    exe = os.path.join(os.path.dirname(sys.executable), "pfem2x")
    return [exe, *args]


def _wait_for(cond, proc, timeout=120.0):
    t0 = time.time()
    while not cond():
        assert proc.poll() is None, "the run ended before it could be interrupted"
        assert time.time() - t0 < timeout
        time.sleep(0.02)


def _meta_step(out):
    f = find_checkpoint(out)
    return f[1]["step"] if f else 0


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns serial runs")
def test_sigkill_then_resume_gives_the_uninterrupted_result(tmp_path):
    scene = _write_scene(tmp_path / "long.toml")
    full = tmp_path / "full"
    assert subprocess.run(_pfem2x("run", str(scene), "--out", str(full), "--quiet")).returncode == 0
    out = tmp_path / "run"
    proc = subprocess.Popen(_pfem2x("run", str(scene), "--out", str(out), "--quiet"))
    _wait_for(lambda: _meta_step(out) >= 60, proc)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    r = subprocess.run(_pfem2x("run", "--resume", str(out)), capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "resuming" in r.stderr
    a = json.loads((full / "summary.json").read_text())
    b = json.loads((out / "summary.json").read_text())
    assert b["status"] == "ok" and b["steps"] == a["steps"] == 1200
    assert b["metrics"] == a["metrics"]
    assert rows(out / "diagnostics.csv") == rows(full / "diagnostics.csv")


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="spawns serial runs")
def test_sigterm_writes_a_checkpoint_and_exits_143(tmp_path):
    scene = _write_scene(tmp_path / "long.toml")
    out = tmp_path / "run"
    proc = subprocess.Popen(
        _pfem2x("run", str(scene), "--out", str(out), "--set", "output.checkpoint_every=0"),
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_for(lambda: (out / "diagnostics.csv").is_file()
              and len((out / "diagnostics.csv").read_text().splitlines()) > 5, proc)  # fmt: skip
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143
    assert "interrupted by SIGTERM" in err and "--resume" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted"
    found = find_checkpoint(out)
    assert found is not None and found[1]["step"] == summary["steps"] > 0
