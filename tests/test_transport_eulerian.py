"""Eulerian θ-method: measured convergence orders and periodic transport (mesh solves)."""

import math

import numpy as np
import pytest

from pfem2x.compat import MPI
from pfem2x.runner import build_domain, make_solver
from pfem2x.scene import validate

A, KAPPA, K = 1.0, 0.02, 2.0 * math.pi
# exact: a decaying sine wave travelling at speed A on the periodic unit interval
EXACT = f"exp(-{KAPPA}*{K}**2*t)*sin({K}*(x - {A}*t))"


def periodic_wave(cells, dt, theta, t_end=0.5, frame="eulerian", diffusion=True):
    raw = {
        "scene": {"name": "wave"},
        "mesh": {"kind": "interval", "bounds": [0.0, 1.0], "cells": [cells], "periodic": [True]},
        "effects": {"advection": True, "diffusion": diffusion},
        "transport": {
            "velocity": [A],
            "kappa": KAPPA,
            "initial": EXACT,
            "exact": EXACT if diffusion else f"sin({K}*(x - {A}*t))",
        },
        "time": {"t_end": t_end, "dt": dt},
        "method": {"frame": frame, "theta": theta, "particles_per_cell": 12},
    }
    return validate(raw)


def final_error(scene):
    comm = MPI.COMM_WORLD
    solver = make_solver(scene, build_domain(scene, comm))
    dt, t_end = scene.time.dt, scene.time.t_end
    steps = round(t_end / dt)
    t = 0.0
    for k in range(steps):
        solver.step(t, dt)
        t = (k + 1) * dt
    return solver.diagnostics(t)["l2_error"], solver


def orders(errs):
    return [math.log2(a / b) for a, b in zip(errs[:-1], errs[1:], strict=True)]


@pytest.mark.mpi
def test_space_convergence_is_second_order():
    # dt small enough that the O(dt^2) Crank-Nicolson error is far below the mesh error
    errs = [final_error(periodic_wave(n, 1.0 / 2000, 0.5, t_end=0.25))[0] for n in (16, 32, 64)]
    p = orders(errs)
    assert all(1.8 < q < 2.3 for q in p), (errs, p)


@pytest.mark.mpi
@pytest.mark.parametrize("theta, expected", [(0.5, 2.0), (1.0, 1.0)])
def test_time_convergence_order_of_theta_method(theta, expected):
    # fine mesh: the spatial error (~1e-4) is well below the time error
    errs = [final_error(periodic_wave(400, dt, theta))[0] for dt in (0.025, 0.0125, 0.00625)]
    p = orders(errs)
    assert all(abs(q - expected) < 0.3 for q in p), (errs, p)


@pytest.mark.mpi
def test_periodic_advection_returns_after_one_period():
    # one period of pure advection at Courant 0.25; CN Galerkin is non-dissipative
    err, solver = final_error(periodic_wave(64, 1.0 / 256, 0.5, t_end=1.0, diffusion=False))
    assert err < 0.01
    arr = solver.T.x.array
    peak = solver.comm.allreduce(arr.max(), op=MPI.MAX)
    assert peak > 0.98
    # the nodes at x = 0 and x = 1 are the same point of the periodic mesh
    x = solver.coords[:, 0]
    lo = arr[np.isclose(x, 0.0)]
    hi = arr[np.isclose(x, 1.0)]
    vals = solver.comm.allgather((lo.tolist(), hi.tolist()))
    lo_all = [v for a, _ in vals for v in a]
    hi_all = [v for _, b in vals for v in b]
    assert lo_all and hi_all
    assert max(lo_all) == pytest.approx(min(hi_all), abs=1e-10)


@pytest.mark.mpi
def test_periodic_rectangle_constraint_counts():
    from pfem2x.periodic import PeriodicConstraint

    raw = {
        "scene": {"name": "p"},
        "mesh": {
            "kind": "rectangle",
            "bounds": [[0, 0], [2, 1]],
            "cells": [6, 4],
            "periodic": [True, True],
        },
        "effects": {"diffusion": True},
        "transport": {"kappa": 1.0},
        "time": {"t_end": 1.0, "dt": 0.1},
    }
    s = validate(raw)
    dom = build_domain(s, MPI.COMM_WORLD)
    solver = make_solver(s, dom)
    pc = solver.periodic_constraint()
    assert isinstance(pc, PeriodicConstraint)
    # 7 x 5 points, doubly periodic: a 6 x 4 torus of distinct points
    assert pc.num_reduced == 6 * 4
    assert pc.num_slaves == 7 * 5 - 6 * 4
    # every row of P has exactly one unit entry
    rows = pc.P.getOwnershipRange()
    for r in range(*rows):
        cols, vals = pc.P.getRow(r)
        assert len(cols) == 1 and vals[0] == 1.0
