"""Runner behaviour: effects select operators, divergence guard, parallel summaries."""

import json
import time

import numpy as np
import pytest

from pfem2x import fem
from pfem2x.compat import MPI
from pfem2x.physics.base import Solver
from pfem2x.runner import Simulation, build_domain, make_solver
from pfem2x.scene import validate

BASE = {
    "scene": {"name": "t"},
    "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [8, 8]},
    "effects": {"diffusion": True},
    "transport": {"kappa": 0.01, "initial": "sin(pi*x)*sin(pi*y)", "boundary_value": 0},
    "time": {"t_end": 0.2, "dt": 0.05},
    "output": {"png": False, "particles": False},
}


def scene(**over):
    raw = json.loads(json.dumps(BASE))
    for dotted, v in over.items():
        sec, key = dotted.split("__")
        if v is None:
            raw.get(sec, {}).pop(key, None)
        else:
            raw.setdefault(sec, {})[key] = v
    return validate(raw)


def test_removing_an_effect_removes_its_term():
    comm = MPI.COMM_WORLD
    on = make_solver(s := scene(), build_domain(s, comm))
    off = make_solver(s2 := scene(effects__diffusion=False), build_domain(s2, comm))
    assert "diffusion" in on.terms and "diffusion" not in off.terms
    peak0 = on.diagnostics(0.0)["max"]
    for k in range(4):
        on.step(0.05 * k, 0.05)
        off.step(0.05 * k, 0.05)
    # Diffusion decays the sine mode by exp(-2 pi^2 kappa t) (0.961 at t = 0.2);
    # without it nothing moves.
    assert on.diagnostics(0.2)["max"] < 0.975 * peak0
    assert off.diagnostics(0.2)["max"] == pytest.approx(peak0, rel=1e-10)


def test_operators_built_once_when_coefficients_are_steady(shared_tmp):
    res = Simulation(scene(), shared_tmp / "a", quiet=True).run()
    assert res.summary["operators"]["matrix_assemblies"] == 1
    assert res.summary["operators"]["solves"] == 4


@pytest.mark.mpi
def test_divergence_guard(shared_tmp):
    # Explicit Euler of dT/dt = +1e3 T (reaction with c < 0) overflows within a few steps.
    s = scene(
        effects__reaction=True,
        transport__reaction=-1e3,
        method__theta=0.0,
        time__t_end=20.0,
        time__dt=0.05,
    )
    res = Simulation(s, shared_tmp / "div", quiet=True).run()
    assert res.status == "diverged" and res.exit_code == 3
    msg = res.summary["message"]
    assert "diverged in step" in msg and ("not finite" in msg or "NaN/Inf" in msg), msg
    assert res.summary["steps"] < 399
    if MPI.COMM_WORLD.rank == 0:
        assert (shared_tmp / "div" / "last_good.xdmf").is_file()
        saved = json.loads((shared_tmp / "div" / "summary.json").read_text())
        assert saved["status"] == "diverged"


@pytest.mark.mpi
def test_parallel_run_matches_serial_metric(shared_tmp):
    res = Simulation(scene(), shared_tmp / "p", quiet=True).run()
    # The discrete solution does not depend on the partition: compare with the exact decay.
    peak = res.history[-1]["max"]
    assert peak == pytest.approx(np.exp(-2 * np.pi**2 * 0.01 * 0.2), rel=0.02)
    assert res.summary["mpi_size"] == MPI.COMM_WORLD.size
    assert fem.COUNTERS["solves"] >= 4


def test_adaptive_dt_holds_the_courant_number(shared_tmp):
    # Speed grows 1 -> 3 over the run: a fixed step would triple its Courant number.
    s = scene(
        effects__diffusion=False,
        effects__advection=True,
        transport__velocity=["1 + t", "0"],
        transport__boundary_value=0,
        time__dt=None,
        time__courant=2.0,
        time__adaptive=True,
        time__t_end=2.0,
    )
    res = Simulation(s, shared_tmp / "ad", quiet=True).run()
    sm = res.summary
    assert sm["status"] == "ok" and res.history[-1]["t"] == pytest.approx(2.0)
    # each step is chosen at Courant 2 from the speed at its start; the summary reports the
    # Courant number reached, with the larger speed 1 + t of the step's end
    ts = [h["t"] for h in res.history]
    reached = max((1.0 + b) / (1.0 + a) for a, b in zip(ts, ts[1:], strict=False))
    assert 2.0 * reached > 2.2  # the speed grows by a tenth or more within the first step
    assert sm["courant_max"] == pytest.approx(2.0 * reached, rel=1e-9)
    assert sm["dt_min"] < 0.5 * sm["dt"]  # the step shrank as the flow sped up


@pytest.mark.mpi
def test_every_rank_finds_the_summary_when_run_returns(shared_tmp):
    """Rank 0 writes summary.json; no rank returns from run() before it is on disk
    (scripts under mpirun read a run's files right after it)."""
    for i in range(3):
        res = Simulation(scene(), shared_tmp / f"s{i}", quiet=True).run()
        saved = json.loads((shared_tmp / f"s{i}" / "summary.json").read_text())
        assert saved["steps"] == res.summary["steps"]


def test_nested_timer_blocks_count_once():
    """A ``timer`` block inside another counts for its own key only (the outer excludes it)."""

    class Timed:
        timings: dict = {}

    t = Timed()
    t.timings = {}
    t0 = time.perf_counter()
    with Solver.timer(t, "assembly"):
        time.sleep(0.01)
        with Solver.timer(t, "solve"):
            time.sleep(0.1)
    total = time.perf_counter() - t0
    assert t.timings["solve"] >= 0.1
    assert t.timings["assembly"] < t.timings["solve"]
    assert t.timings["assembly"] + t.timings["solve"] <= total
