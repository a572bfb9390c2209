"""PNG snapshots: none when none is asked for, no renderer probe for 2D, the probe cached."""

import json

import pytest

from pfem2x import io as pio
from pfem2x import picture
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


def _diffusion_sim(out, **output):
    """A 2D diffusion scene to t = 0.2 (dt 0.05) with the PNG settings ``output``."""
    raw = {
        "scene": {"name": "t"},
        "mesh": {"kind": "rectangle", "bounds": [[0, 0], [2, 1]], "cells": [8, 4]},
        "effects": {"diffusion": True},
        "transport": {"kappa": 0.01, "initial": "sin(pi*x/2)*sin(pi*y)", "boundary_value": 0},
        "time": {"t_end": 0.2, "dt": 0.05},
        "output": {"fields": False, "csv": False, **output},
    }
    return Simulation(validate(raw), out, quiet=True)


def _diffusion_run(out, **output):
    """:func:`_diffusion_sim`, run."""
    return _diffusion_sim(out, **output).run()


def test_default_png_times_are_first_and_last_without_probe(tmp_path, no_probe):
    res = _diffusion_run(tmp_path / "r")  # no output.png_times: t = 0 and t_end
    assert res.status == "ok"
    names = sorted(p.name for p in (tmp_path / "r").glob("*.png"))
    assert names == ["T_t0000.000.png", "T_t0000.200.png"]
    assert no_probe == []  # 2D pictures are drawn with Pillow


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
    monkeypatch.setattr(picture, "_CANVAS", [])
    pio.png_snapshot(tmp_path / "a.png", u, "first", contour=0.0, label="T", segments=seg)
    canvas = picture._CANVAS[0]
    u.x.array[:] *= 3.0
    pio.png_snapshot(tmp_path / "b.png", u, "second", clim=(0.0, 1.0), label="T")
    assert picture._CANVAS[0] is canvas, "the figure was not reused"
    picture._CANVAS.clear()
    pio.png_snapshot(tmp_path / "c.png", u, "second", clim=(0.0, 1.0), label="T")
    assert picture._CANVAS[0] is not canvas
    assert (tmp_path / "b.png").read_bytes() == (tmp_path / "c.png").read_bytes()
    assert (tmp_path / "a.png").read_bytes() != (tmp_path / "b.png").read_bytes()
    other = dolfinx.mesh.create_unit_square(MPI.COMM_SELF, 4, 4)
    w = dolfinx.fem.Function(compat.function_space(other, 1))
    pio.png_snapshot(tmp_path / "d.png", w, "another mesh")
    assert picture._CANVAS[0].coords.shape[0] == 32, "a new mesh needs a new figure"


def _triangles(nx, ny, lo=(0.0, 0.0), hi=(1.0, 1.0), jitter=0.3):
    """A perturbed ``nx`` x ``ny`` triangulation of a box as ``(n, 3, 2)`` vertex coordinates."""
    import numpy as np

    rng = np.random.default_rng(0)
    x, y = np.meshgrid(np.linspace(lo[0], hi[0], nx + 1), np.linspace(lo[1], hi[1], ny + 1))
    inner = (x > lo[0]) & (x < hi[0]) & (y > lo[1]) & (y < hi[1])
    x = x + inner * rng.uniform(-jitter, jitter, x.shape) * (hi[0] - lo[0]) / nx
    y = y + inner * rng.uniform(-jitter, jitter, y.shape) * (hi[1] - lo[1]) / ny
    p = np.stack([x.ravel(), y.ravel()], 1)
    k = np.arange((nx + 1) * (ny + 1)).reshape(ny + 1, nx + 1)
    a, b, c, d = k[:-1, :-1].ravel(), k[:-1, 1:].ravel(), k[1:, :-1].ravel(), k[1:, 1:].ravel()
    return p[np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])]


@pytest.mark.parametrize("cells, shape", [((3, 5), (40, 30)), ((60, 40), (17, 23))])
def test_raster_is_the_p1_field_at_every_pixel_centre(cells, shape, monkeypatch):
    """A linear field is exact at each pixel centre; a box's raster is covered once.

    Coarse triangles (many pixels each) and fine ones (several per pixel), the
    candidates in one chunk and in chunks of 64.
    """
    import numpy as np

    from pfem2x import picture

    coords = _triangles(*cells, lo=(-1.0, 0.5), hi=(2.0, 2.5))
    lo, hi = np.array([-1.0, 0.5]), np.array([2.0, 2.5])
    rows, cols = shape
    j, i = np.divmod(np.arange(rows * cols), cols)
    cx = lo[0] + (i + 0.5) * (hi[0] - lo[0]) / cols
    cy = lo[1] + (j + 0.5) * (hi[1] - lo[1]) / rows
    first = None
    for chunk in (1 << 22, 64):
        monkeypatch.setattr(picture, "_CHUNK", chunk)
        pix, cell, w = picture.raster_weights(coords, lo, hi, shape)
        assert np.array_equal(pix, np.arange(rows * cols)), "every pixel once"
        assert np.all(w >= -1e-9) and np.allclose(w.sum(1), 1.0)
        assert np.allclose(np.einsum("ij,ijk->ik", w, coords[cell]), np.stack([cx, cy], 1))
        vals = 3.0 * coords[..., 0] - 2.0 * coords[..., 1]
        got = np.einsum("ij,ij->i", w, vals[cell])
        assert np.allclose(got, 3.0 * cx - 2.0 * cy, atol=1e-12)
        if first is None:
            first = (cell, w)
        else:
            assert np.array_equal(first[0], cell) and np.allclose(first[1], w)


def test_raster_leaves_pixels_outside_the_mesh_blank():
    """An L-shaped mesh: the pixels of the missing quarter are not covered, all others are."""
    import numpy as np

    from pfem2x import picture

    box = _triangles(8, 8, hi=(2.0, 2.0), jitter=0.0)
    centre = box.mean(axis=1)
    L = box[~((centre[:, 0] > 1.0) & (centre[:, 1] > 1.0))]
    pix, _cell, _w = picture.raster_weights(L, np.zeros(2), np.full(2, 2.0), (20, 20))
    j, i = np.divmod(pix, 20)
    assert len(pix) == 300
    assert not np.any((i >= 10) & (j >= 10))


def _early_stop(out, png_times, stop_at, how):
    """The diffusion run of :func:`_diffusion_run` (4 steps of 0.05), stopped after step
    ``stop_at`` by a divergence (``how = "diverge"``) or by SIGTERM (``"signal"``)."""
    import os
    import signal

    from pfem2x.runner import Diverged

    sim = _diffusion_sim(out, png_times=png_times)

    def hook(sim, step, t):
        if step == stop_at and how == "diverge":
            raise Diverged(f"T not finite after step {step}")
        if step == stop_at and how == "signal":
            os.kill(os.getpid(), signal.SIGTERM)

    sim.on_step = hook
    return sim.run()


def test_a_run_that_stops_early_draws_its_end(tmp_path, no_probe, monkeypatch):
    """A diverged run draws its last good state, an interrupted one its state at the stop,
    each named by the time it shows; a failure to draw leaves the run's outcome alone."""
    res = _early_stop(tmp_path / "d", [0.0, 0.2], 2, "diverge")
    assert (res.status, res.exit_code) == ("diverged", 3), res.summary["message"]
    names = sorted(p.name for p in (tmp_path / "d").glob("*.png"))
    assert names == ["T_t0000.000.png", "T_t0000.100.png"]  # the last good state: t = 0.1

    res = _early_stop(tmp_path / "i", [0.0, 0.2], 3, "signal")
    assert (res.status, res.exit_code) == ("interrupted", 143)
    names = sorted(p.name for p in (tmp_path / "i").glob("*.png"))
    assert names == ["T_t0000.000.png", "T_t0000.150.png"]

    def broken(*args, **kwargs):
        raise RuntimeError("no canvas")

    monkeypatch.setattr(pio, "png_snapshot", broken)
    res = _early_stop(tmp_path / "b", [0.2], 2, "diverge")
    assert (res.status, res.exit_code) == ("diverged", 3)
    assert json.loads((tmp_path / "b" / "summary.json").read_text())["status"] == "diverged"
    assert list((tmp_path / "b").glob("*.png")) == []


def test_non_finite_values_are_blank_pixels(tmp_path):
    """A field with NaN and inf is drawn: those pixels blank, the range of the finite values."""
    import numpy as np

    coords = _triangles(4, 4, jitter=0.0)
    vals = coords[..., 0].copy()
    vals[:3] = np.nan
    vals[3] = np.inf
    picture.png_2d(tmp_path / "a.png", coords, vals, "t", None, None, "T")
    assert (tmp_path / "a.png").stat().st_size > 1000
    assert "[0, 1]" in picture._CANVAS[0].bar_label
    picture.png_2d(tmp_path / "b.png", coords, np.full_like(vals, np.nan), "t", None, None, "T")
    assert (tmp_path / "b.png").is_file()


def test_ticks_are_round_values_within_the_range():
    """At most the asked number of multiples of 1, 2, 2.5 or 5 x 10^k, labelled by the step."""
    import numpy as np

    assert np.allclose(picture.nice_ticks(-0.5, 0.5, 3), [-0.5, 0.0, 0.5])
    assert np.allclose(picture.nice_ticks(-2.0, 2.0, 13), np.arange(-2.0, 2.01, 0.5))
    assert picture.tick_labels(picture.nice_ticks(-0.5, 0.5, 3)) == ["-0.5", "0.0", "0.5"]
    assert picture.tick_labels(np.array([0.0, 0.25, 0.5])) == ["0.00", "0.25", "0.50"]
    assert picture.tick_labels(np.array([0.0, 500.0, 1000.0])) == ["0", "500", "1000"]
    assert picture.tick_labels(np.array([-1e-17, 0.1])) == ["0.0", "0.1"]
    assert list(picture.nice_ticks(1.0, 1.0, 5)) == [1.0]
    rng = np.random.default_rng(1)
    for _ in range(500):
        lo = rng.uniform(-1e3, 1e3) * 10.0 ** rng.integers(-6, 3)
        hi = lo + rng.uniform(1e-3, 1e3) * 10.0 ** rng.integers(-6, 3)
        most = int(rng.integers(2, 12))
        t = picture.nice_ticks(lo, hi, most)
        assert 1 <= len(t) <= most, (lo, hi, most, t)
        assert t.min() >= lo - 1e-9 * (hi - lo) and t.max() <= hi + 1e-9 * (hi - lo)
        assert len(set(picture.tick_labels(t))) == len(t), "labels tell the ticks apart"


def test_iso_line_of_a_linear_field_is_exact():
    """The segments of ``x - 0.3 = 0`` on a perturbed mesh lie on x = 0.3 and span it once."""
    import numpy as np

    coords = _triangles(7, 5, jitter=0.3)
    seg = picture.iso_segments(coords, coords[..., 0] - 0.3, 0.0)
    assert np.allclose(seg[..., 0], 0.3, atol=1e-12)
    assert np.isclose(np.abs(seg[:, 1, 1] - seg[:, 0, 1]).sum(), 1.0, atol=1e-12)
    assert len(picture.iso_segments(coords, coords[..., 0], 5.0)) == 0


def test_the_picture_is_the_field_in_viridis_with_the_interface_in_red(tmp_path, monkeypatch):
    """Each pixel of the plot has viridis's colour of the P1 value at its centre; the
    interface's pixels are red, pixels 3 or more away from it are the field's; blank
    (white) where the values are not finite."""
    import numpy as np
    from PIL import Image

    monkeypatch.setattr(picture, "_CANVAS", [])
    coords = _triangles(6, 4, hi=(2.0, 1.0), jitter=0.3)
    picture.png_2d(tmp_path / "a.png", coords, coords[..., 0] / 2.0, "t", (0.0, 1.0), None, "s")
    canvas = picture._CANVAS[0]
    (left, top), (rows, cols) = canvas.box, canvas.shape
    plot = np.asarray(Image.open(tmp_path / "a.png").convert("RGB"))
    plot = plot[top : top + rows, left : left + cols].astype(int)
    xc = (np.arange(cols) + 0.5) / cols  # the field x / 2 at the pixel centres
    index = np.minimum(np.floor(xc * 256), 255).astype(int)
    lut = picture._viridis().astype(int)
    near = [(lut[np.clip(index + k, 0, 255)][None] == plot).all(-1) for k in (0, -1, 1)]
    assert np.mean(near[0]) > 0.999, "the field's colours"
    assert np.all(near[0] | near[1] | near[2]), "(a centre on a colour's edge: either side)"
    line = np.array([[[0.0, 0.5], [2.0, 0.5]]])
    picture.png_2d(
        tmp_path / "b.png", coords, coords[..., 0] / 2.0, "t", (0.0, 1.0), None, "s", line
    )
    drawn = np.asarray(Image.open(tmp_path / "b.png").convert("RGB"))
    drawn = drawn[top : top + rows, left : left + cols].astype(int)
    row = rows / 2.0  # the line y = 0.5 between pixel rows rows/2 - 1 and rows/2
    centre = drawn[int(row) - 1 : int(row) + 1]
    assert np.all(centre[..., 0] >= 230) and np.all(centre[..., 1] <= 120), "red on the line"
    far = np.abs(np.arange(rows) + 0.5 - row) >= 3.0
    assert np.array_equal(drawn[far], plot[far]), "nothing drawn away from the line"
    edge = np.array([[[-1.0, 1.0], [3.0, 1.0]], [[0.5, -0.5], [0.5, -0.02]]])  # on and off the box
    picture.png_2d(
        tmp_path / "d.png", coords, coords[..., 0] / 2.0, "t", (0.0, 1.0), None, "s", edge
    )
    drawn = np.asarray(Image.open(tmp_path / "d.png").convert("RGB"))
    drawn = drawn[top : top + rows, left : left + cols].astype(int)
    assert np.all(drawn[0, :, 0] >= 200), "the top row half covered"
    assert np.array_equal(drawn[3:], plot[3:]), "nothing drawn but near the top edge"
    nan = np.full_like(coords[..., 0], np.nan)
    picture.png_2d(tmp_path / "c.png", coords, nan, "t", None, None, "s")
    blank = np.asarray(Image.open(tmp_path / "c.png").convert("RGB"))
    assert np.all(blank[top : top + rows, left : left + cols] == 255)
