"""PNG snapshots: none when none is asked for, no renderer probe for 2D, the probe cached."""

import json

import pytest

from pfem2x import io as pio
from pfem2x.runner import Simulation
from pfem2x.scene import load_scene, validate

QUICK = ["output.fields=false", "output.csv=false"]


@pytest.fixture
def no_probe(monkeypatch):
    """Fail on the pyvista probe (a child process)."""
    calls = []

    def fail():
        calls.append(1)
        raise AssertionError("pyvista probe started")

    monkeypatch.setattr(pio, "_run_probe", fail)
    monkeypatch.setattr(pio, "_PYVISTA_OK", None)
    return calls


@pytest.mark.parametrize("over", [["output.png_times=[]"], ["output.png=false"]])
def test_no_png_when_none_is_asked_for(tmp_path, no_probe, over):
    scene = load_scene("gaussian-hill", QUICK + over, "small")
    res = Simulation(scene, tmp_path / "r", quiet=True).run()
    assert res.status == "ok"
    assert list((tmp_path / "r").glob("*.png")) == []
    assert no_probe == []


def _diffusion_run(out, **output):
    """A 2D diffusion scene to t = 0.2 (dt 0.05) with the PNG settings ``output``."""
    raw = {
        "scene": {"name": "t"},
        "mesh": {"kind": "rectangle", "bounds": [[0, 0], [2, 1]], "cells": [8, 4]},
        "effects": {"diffusion": True},
        "transport": {"kappa": 0.01, "initial": "sin(pi*x/2)*sin(pi*y)", "boundary_value": 0},
        "time": {"t_end": 0.2, "dt": 0.05},
        "output": {"fields": False, "csv": False, **output},
    }
    return Simulation(validate(raw), out, quiet=True).run()


def test_default_png_times_are_first_and_last_without_probe(tmp_path, no_probe):
    res = _diffusion_run(tmp_path / "r")  # no output.png_times: t = 0 and t_end
    assert res.status == "ok"
    names = sorted(p.name for p in (tmp_path / "r").glob("*.png"))
    assert names == ["T_t0000.000.png", "T_t0000.200.png"]
    assert no_probe == []  # 2D pictures are drawn with matplotlib


def test_a_png_time_beyond_t_end_is_named_by_the_time_it_shows(tmp_path, no_probe):
    res = _diffusion_run(tmp_path / "r", png_times=[0.1, 1.0])
    assert res.status == "ok"
    names = sorted(p.name for p in (tmp_path / "r").glob("*.png"))
    assert names == ["T_t0000.100.png", "T_t0000.200.png"]


def test_probe_runs_once_per_installation(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("PFEM2X_PNG_BACKEND", raising=False)
    monkeypatch.setattr(pio.importlib.util, "find_spec", lambda name: object())
    calls = []

    def fake_probe():
        calls.append(1)
        return True

    monkeypatch.setattr(pio, "_run_probe", fake_probe)
    for _ in range(3):  # three processes: the cache file answers the second and third
        monkeypatch.setattr(pio, "_PYVISTA_OK", None)
        assert pio.pyvista_usable() is True
    assert len(calls) == 1
    cache = json.loads(pio.probe_cache_file().read_text())
    assert list(cache.values()) == [True]
    assert str(tmp_path) in str(pio.probe_cache_file())


def test_snapshots_of_one_mesh_reuse_the_figure_without_stale_artists(tmp_path, monkeypatch):
    """The second snapshot of a mesh redraws the first one's figure (the 2D canvas).

    What one snapshot draws (an iso-line, the interface, the range, the title) must not
    remain in the next: a snapshot made on the reused figure is byte-identical to the
    same snapshot made on a new one.
    """
    import numpy as np

    from pfem2x import compat
    from pfem2x.compat import MPI, dolfinx

    if MPI.COMM_WORLD.size > 1:
        pytest.skip("serial")
    msh = dolfinx.mesh.create_unit_square(MPI.COMM_SELF, 8, 4)
    u = dolfinx.fem.Function(compat.function_space(msh, 1))
    u.interpolate(lambda x: x[0] - 0.5)
    seg = np.array([[[0.2, 0.1], [0.6, 0.9]]])
    monkeypatch.setattr(pio, "_CANVAS", [])
    pio.png_snapshot(tmp_path / "a.png", u, "first", contour=0.0, label="T", segments=seg)
    canvas = pio._CANVAS[0]
    u.x.array[:] *= 3.0
    pio.png_snapshot(tmp_path / "b.png", u, "second", clim=(0.0, 1.0), label="T")
    assert pio._CANVAS[0] is canvas, "the figure was not reused"
    pio._CANVAS.clear()
    pio.png_snapshot(tmp_path / "c.png", u, "second", clim=(0.0, 1.0), label="T")
    assert pio._CANVAS[0] is not canvas
    assert (tmp_path / "b.png").read_bytes() == (tmp_path / "c.png").read_bytes()
    assert (tmp_path / "a.png").read_bytes() != (tmp_path / "b.png").read_bytes()
    other = dolfinx.mesh.create_unit_square(MPI.COMM_SELF, 4, 4)
    w = dolfinx.fem.Function(compat.function_space(other, 1))
    pio.png_snapshot(tmp_path / "d.png", w, "another mesh")
    assert pio._CANVAS[0].coords.shape[0] == 32, "a new mesh needs a new figure"
