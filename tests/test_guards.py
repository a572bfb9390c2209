"""Divergence guards (runaway Courant number, kinetic energy) and flat memory over long runs."""

import ctypes
import gc
import json
import os
import tracemalloc

import numpy as np
import pytest

from pfem2x.compat import MPI
from pfem2x.runner import Simulation
from pfem2x.scene import validate


def _scene(raw):
    return validate(json.loads(json.dumps(raw)))


ACCEL = {  # a velocity that grows without bound: 1 + 100 t^2
    "scene": {"name": "runaway"},
    "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [8, 8]},
    "effects": {"advection": True},
    "transport": {"velocity": ["1 + 100*t*t", "0"], "initial": "x"},
    "time": {"t_end": 2.0, "dt": 0.01, "max_courant": 5.0},
    "method": {"frame": "lagrangian"},
    "output": {"png": False},
}


@pytest.mark.mpi
def test_runaway_courant_stops_with_last_good_state(shared_tmp):
    raw = dict(ACCEL)
    raw["mesh"] = {**raw["mesh"], "periodic": [True, True]}
    res = Simulation(_scene(raw), shared_tmp / "c", quiet=True).run()
    assert res.status == "diverged" and res.exit_code == 3
    msg = res.summary["message"]
    assert "Courant number" in msg and "time.max_courant" in msg and "step" in msg, msg
    # (1 + 100 t^2) 0.01 / (1/8) > 5 from t = 0.78 on
    assert 0.7 < res.summary["t_end"] < 0.85
    if MPI.COMM_WORLD.rank == 0:
        assert (shared_tmp / "c" / "last_good.xdmf").is_file()
        vtp = (shared_tmp / "c" / "last_good_particles.vtp").read_bytes()
        assert b"NumberOfPoints" in vtp
        assert json.loads((shared_tmp / "c" / "summary.json").read_text())["status"] == "diverged"


def test_courant_guard_default_is_generous():
    s = _scene(ACCEL | {"time": {"t_end": 1.0, "dt": 0.01}})
    assert s["time"]["max_courant"] is None  # 50 x time.courant, or 1000 with time.dt


FLOW = {  # a channel filling from rest: the kinetic energy grows from 0
    "scene": {"name": "energy", "physics": "flow"},
    "mesh": {"kind": "rectangle", "bounds": [[0, 0], [2, 1]], "cells": [8, 4]},
    "effects": {"viscosity": True},
    "phases": {"water": {"density": 1.0, "viscosity": 0.01}},
    "flow": {
        "walls": "noslip",
        "left": "inflow",
        "right": "outflow",
        "inflow_velocity": ["min(1, 10*t)*4*y*(1-y)", "0"],
        "velocity_scale": 0.1,
    },
    "time": {"t_end": 1.0, "dt": 0.05, "max_energy_growth": 2.0},
    "method": {"frame": "eulerian"},
    "output": {"png": False},
}


@pytest.mark.mpi
def test_energy_guard(shared_tmp):
    # the inflow doubles from step 1 to 2 (ramp): the energy grows ~4x in one step, above
    # 2 x max(initial, peak, reference 1/2 rho U^2 |Omega| = 0.01)
    res = Simulation(_scene(FLOW), shared_tmp / "e", quiet=True).run()
    assert res.status == "diverged" and res.exit_code == 3
    msg = res.summary["message"]
    assert "kinetic energy" in msg and "time.max_energy_growth" in msg, msg
    assert res.summary["steps"] < 20
    comm = MPI.COMM_WORLD
    saved = comm.bcast((shared_tmp / "e" / "last_good.xdmf").is_file() if comm.rank == 0 else None)
    assert saved  # on every rank: the run below is collective
    # the default bound (100 x) lets the same flow run
    raw = json.loads(json.dumps(FLOW))
    raw["time"].pop("max_energy_growth")
    ok = Simulation(_scene(raw), shared_tmp / "ok", quiet=True).run()
    assert ok.status == "ok", ok.summary["message"]


# -- memory -------------------------------------------------------------------------------
MEMORY = {
    "scene": {"name": "memory"},
    "mesh": {"kind": "rectangle", "bounds": [[-1, -1], [1, 1]], "cells": [32, 32]},
    "effects": {"advection": True},
    "transport": {"velocity": ["-y", "x"], "initial": "exp(-20*((x-0.4)**2 + y**2))"},
    "time": {"t_end": 0.4, "dt": 0.001},
    "method": {"frame": "lagrangian"},  # no population control: a fixed particle count
    "output": {"png": False, "fields": False, "particles": False, "csv": True},
}
#: allowed growth of traced (Python / NumPy) memory between steps 50 and 400; the run keeps
#: one diagnostics row per step (~0.6 kB), a leak of one P1 vector per step adds 8.7 kB
TRACED_BOUND = 1.0e6
#: allowed growth of the resident set (everything, PETSc too)
RSS_BOUND = 8.0e6


def _rss() -> float:
    """Resident set size in bytes, after giving freed heap back to the OS.

    Without the trim, heap that earlier tests in this process freed but glibc kept (large
    NumPy temporaries raise its mmap threshold) is reused first and hides growth.
    """
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def _growth(tmp, leak: int = 0) -> tuple[float, float]:
    """Traced and RSS growth from step 50 to step 400; ``leak``: P1 vectors leaked per step."""
    sim = Simulation(_scene(MEMORY), tmp, quiet=True, overwrite=True)
    kept: list[np.ndarray] = []
    at: dict[int, tuple[float, float]] = {}

    def hook(s, step, t):
        for _ in range(leak):
            kept.append(s.solver.T.x.array.copy())
        if step in (50, 400):
            gc.collect()
            at[step] = (tracemalloc.get_traced_memory()[0], _rss())

    sim.on_step = hook
    tracemalloc.start()
    try:
        res = sim.run()
    finally:
        tracemalloc.stop()
    assert res.status == "ok" and res.summary["steps"] == 400
    return at[400][0] - at[50][0], at[400][1] - at[50][1]


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial memory measurement")
def test_memory_stays_flat_over_a_long_run(tmp_path):
    traced, rss = _growth(tmp_path / "m")
    print(f"growth from step 50 to 400: traced {traced:.0f} B, RSS {rss:.0f} B")
    assert traced < TRACED_BOUND, traced
    assert rss < RSS_BOUND, rss


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="serial memory measurement")
def test_memory_bound_catches_a_leak_of_one_vector_per_step(tmp_path):
    traced, rss = _growth(tmp_path / "m", leak=1)
    assert traced > TRACED_BOUND, traced  # 350 x 8.7 kB = 3 MB
    # RSS: freed heap from earlier runs in this process is reused first, so leak enough
    # (350 x 32 x 8.7 kB = 97 MB) to exceed any such slack; the bound is 8 MB
    traced, rss = _growth(tmp_path / "m", leak=32)
    assert rss > RSS_BOUND, rss


# -- transport growth guard ---------------------------------------------------------------
def _hill(tmp, *extra):
    from pfem2x.scene import load_scene  # noqa: PLC0415

    over = ["method.frame=eulerian", "method.theta=0", "time.courant=40", "output.png=false"]
    return Simulation(load_scene("gaussian-hill", over + list(extra)), tmp, quiet=True).run()


@pytest.mark.mpi
def test_growth_guard_stops_an_unstable_transport_run(shared_tmp):
    # Explicit Euler at Courant 40: the unit hill grew to 1.7e11 with status "ok" before.
    res = _hill(shared_tmp / "g")
    assert res.status == "diverged" and res.exit_code == 3
    msg = res.summary["message"]
    assert "max|T|" in msg and "time.max_growth" in msg and "diverged in step" in msg, msg
    assert res.history[-1]["max"] < 10.0  # stopped at the first step beyond 10 x the bound
    if MPI.COMM_WORLD.rank == 0:
        assert (shared_tmp / "g" / "last_good.xdmf").is_file()


def test_growth_guard_off_with_zero(tmp_path):
    res = _hill(tmp_path / "g", "time.max_growth=0")
    assert res.status == "ok"
    assert res.summary["metrics"]["max_final"] > 1e6  # the run it used to let through


def test_growth_bound_counts_sources_and_reaction(tmp_path):
    # dT/dt = q - c T with q = 1, c = -0.5 (growth), T0 = 0.1: exact 2.2 e^(t/2) - 2, which
    # outgrows the bound without sources or reaction but stays below the bound with them.
    raw = {
        "scene": {"name": "grow"},
        "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [4, 4]},
        "effects": {"source": True, "reaction": True},
        "transport": {"initial": 0.1, "source": 1.0, "reaction": -0.5},
        "time": {"t_end": 4.0, "dt": 0.1, "max_growth": 1.0},
        "output": {"png": False, "particles": False, "fields": False},
    }
    res = Simulation(_scene(raw), tmp_path / "s", quiet=True).run()
    assert res.status == "ok", res.summary["message"]
    assert res.history[-1]["max"] > 10.0 * 0.1  # 14.3: far above the initial data
