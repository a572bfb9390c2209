"""The last good state copied into the arrays of the state before."""

import json

import numpy as np

from pfem2x.buffers import copy_into
from pfem2x.runner import Simulation
from pfem2x.scene import validate


def test_copy_into_reuses_storage_with_room():
    a = np.arange(12.0).reshape(6, 2)
    first = a.copy()
    b = copy_into(a[:4] + 1, first)  # fewer rows: the same storage
    assert np.shares_memory(b, first) and np.array_equal(b, a[:4] + 1)
    c = copy_into(a * 2, b)  # as many rows as the storage: still it
    assert np.shares_memory(c, first) and np.array_equal(c, a * 2)
    d = copy_into(np.vstack([a, a]), c)  # more: new storage, with room for more
    assert not np.shares_memory(d, first) and np.array_equal(d, np.vstack([a, a]))
    assert len(d.base) == 15
    for other in (a.astype(np.float32), np.arange(6.0), np.ones((6, 3))):
        e = copy_into(other, d)  # another dtype or row shape: new storage
        assert not np.shares_memory(e, d) and np.array_equal(e, other) and e.dtype == other.dtype


def test_a_state_copied_into_the_last_one_equals_a_new_copy(tmp_path):
    raw = {
        "scene": {"name": "state"},
        "mesh": {"kind": "rectangle", "bounds": [[0, 0], [1, 1]], "cells": [6, 6]},
        "effects": {"advection": True},
        "transport": {"velocity": ["1", "0"], "initial": "x"},
        "time": {"t_end": 0.1, "dt": 0.05},
        "method": {"frame": "lagrangian"},
        "output": {"png": False},
    }
    sim = Simulation(validate(json.loads(json.dumps(raw))), tmp_path / "s", quiet=True)
    sim.setup()
    solver, cloud = sim.solver, sim.solver.cloud()
    first = solver.state()
    storage = {k: v for k, v in first.items() if k.startswith(("cloud.x", "cloud.f.", "field."))}
    cloud.x[:, 0] += 0.01
    cloud.remove(np.arange(cloud.n) % 3 == 0)
    again = solver.state(into=first)
    fresh = solver.state()
    assert again.keys() == fresh.keys()
    for k in fresh:
        assert np.array_equal(again[k], fresh[k]), k
    for k, v in storage.items():
        assert np.shares_memory(again[k], v), k
