"""Balanced two-phase gravity: a flat interface inside cells stays at rest, both frames.

Scene ``two-layer-rest`` (heavy below light, exact u = 0 and hydrostatic p) on
16 x 16 cells, 100 steps, the interface at several heights inside a row of
cells, density ratios 3 and 1000. Gravity as ``rho g`` gave spurious speeds of
5e-3 to 1e-1 and volume drifts of 2e-4 to 9e-3 here; the balanced force
(:mod:`pfem2x.physics.flow.balanced`) keeps the fluid at rest to solver
tolerance, and the pressure is the nodal interpolant of the exact one.
"""

import numpy as np
import pytest

from pfem2x.compat import MPI
from pfem2x.physics.flow.balanced import closest_points
from pfem2x.runner import build_domain, make_solver
from pfem2x.scene import load_scene

STEPS, DT = 100, 0.01


def rest_solver(frame: str, y0: float, ratio: int, *extra: str):
    over = [f'method.frame="{frame}"', f"params.y0={y0}", "mesh.cells=[16,16]", *extra]
    sc = load_scene("two-layer-rest", over, variant="ratio1000" if ratio == 1000 else None)
    dom = build_domain(sc, MPI.COMM_WORLD)
    return make_solver(sc, dom), sc


def hydrostatic(s, sc) -> np.ndarray:
    """The exact pressure at the P1 nodes."""
    return s.problem.exact_pressure(s.coords, 0.0)


def run_at_rest(frame: str, y0: float, ratio: int, *extra: str) -> None:
    s, sc = rest_solver(frame, y0, ratio, *extra)
    speed = 0.0
    for k in range(STEPS):
        s.step(k * DT, DT)
        speed = max(speed, s.diagnostics((k + 1) * DT)["speed_max"])
    d = s.diagnostics(STEPS * DT)
    assert speed <= 1e-8  # in units of sqrt(g Hb) = 1
    for name in ("heavy", "light"):
        assert abs(d[f"volume_change_{name}"]) <= 1e-6
    # the discrete pressure is the nodal interpolant of the exact one (up to a constant)
    diff = s.p.x.array - hydrostatic(s, sc)
    lo = s.comm.allreduce(diff.min(), op=MPI.MIN)
    hi = s.comm.allreduce(diff.max(), op=MPI.MAX)
    assert hi - lo <= 1e-6 * ratio


@pytest.mark.parametrize("ratio", [3, 1000])
@pytest.mark.parametrize("y0", [0.5137, 0.5299])
@pytest.mark.parametrize("frame", ["lagrangian", "eulerian"])
def test_flat_interface_inside_cells_stays_at_rest(frame, y0, ratio):
    run_at_rest(frame, y0, ratio)


@pytest.mark.parametrize("frame", ["lagrangian", "eulerian"])
def test_discrete_projection_keeps_the_rest(frame):
    """``flow.divergence_rtol``: a balanced state has no weak divergence left to remove."""
    run_at_rest(frame, 0.5137, 1000, "flow.divergence_rtol=0.05")


@pytest.mark.parametrize(
    "keys",
    [
        ["flow.divergence_rtol=0"],  # PFEM-2's approximate projection
        [  # the total-pressure set (the dam break's alternative at ratio 1000)
            'flow.pressure_step="total"',
            'flow.light_source="gravity"',
            "flow.pic_fraction_light=1.0",
            "flow.mass_weighted=true",
        ],
    ],
)
def test_other_option_sets_keep_the_rest(keys):
    """PFEM-2 at ratio 1000 with keys other than its frame's defaults."""
    run_at_rest("lagrangian", 0.5137, 1000, *keys)


@pytest.mark.mpi
@pytest.mark.parametrize("frame", ["lagrangian", "eulerian"])
def test_flat_interface_at_rest_in_parallel(frame):
    run_at_rest(frame, 0.503, 1000)


@pytest.mark.parametrize("frame", ["lagrangian", "eulerian"])
def test_tilted_interface_moves(frame):
    """Not balanced away: a tilted interface starts to flow (gravity along it)."""
    s, _ = rest_solver(frame, 0.5137, 3, 'phases.heavy.region="y < y0 + 0.2*(x - 0.5)"')
    for k in range(10):
        s.step(k * DT, DT)
    assert s.diagnostics(10 * DT)["speed_max"] > 1e-3


def test_closest_points_on_segments():
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]]])
    pts = np.array([[0.5, -2.0], [2.0, 0.5], [0.2, 0.1], [3.0, 3.0]])
    want = np.array([[0.5, 0.0], [1.0, 0.5], [0.2, 0.0], [1.0, 1.0]])
    assert np.allclose(closest_points(pts, segs), want, atol=1e-15)


@pytest.mark.parametrize("shape", ["wavy", "flat", "upright"])
def test_closest_points_as_all_pairs(shape):
    """The bucketed search: the closest point of all pairs, to the last bit, ties included.

    A polyline of 2000 segments (shared end points: two equidistant segments, the lower
    index wins), wavy or straight (a flat or upright line: a bounding box of no area),
    and points near it, on it and far from it.
    """
    rng = np.random.default_rng(11)
    t = np.linspace(-0.5, 0.5, 2001)
    line = {
        "wavy": np.c_[t, 0.1 * np.cos(2 * np.pi * t) + 0.02 * np.sin(40 * t)],
        "flat": np.c_[t, np.full_like(t, 0.0137)],
        "upright": np.c_[np.full_like(t, 0.2), t],
    }[shape]
    segs = np.stack([line[:-1], line[1:]], axis=1)
    pts = np.concatenate(
        [rng.uniform([-0.6, -0.4], [0.6, 0.4], (3000, 2)), line[::5], line[::7] + [0.0, 1e-3]]
    )
    a, ab = segs[None, :, 0, :], segs[None, :, 1, :] - segs[None, :, 0, :]
    ab2 = np.maximum(ab[..., 0] * ab[..., 0] + ab[..., 1] * ab[..., 1], 1e-300)
    ap = pts[:, None, :] - a
    s = np.clip((ap[..., 0] * ab[..., 0] + ap[..., 1] * ab[..., 1]) / ab2, 0.0, 1.0)
    c = a + s[..., None] * ab
    d = pts[:, None, :] - c
    k = np.argmin(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1], axis=1)
    want = c[np.arange(len(pts)), k]
    assert np.array_equal(closest_points(pts, segs), want)
    assert np.isnan(closest_points(pts[:2], segs[:0])).all()


def test_cut_segments_as_the_vectorised_form():
    """The compiled zero iso-line segments: those of the vectorised edge crossings, to the
    bit (random triangles, signs at random, exact zeros on the positive side)."""
    from pfem2x.physics.flow.interface import cut_segments

    rng = np.random.default_rng(5)
    xy = rng.random((4000, 3, 2))
    vals = rng.standard_normal((4000, 3))
    vals[rng.random((4000, 3)) < 0.1] = 0.0
    pos = vals >= 0
    cut = pos.any(axis=1) & ~pos.all(axis=1)
    v, x, p = vals[cut], xy[cut], pos[cut]
    pts = np.empty((len(v), 3, 2))
    crosses = np.empty((len(v), 3), dtype=bool)
    for e, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
        crosses[:, e] = p[:, i] != p[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(crosses[:, e], v[:, i] / (v[:, i] - v[:, j]), 0.0)
        pts[:, e] = x[:, i] + s[:, None] * (x[:, j] - x[:, i])
    idx = np.argsort(~crosses, axis=1, kind="stable")[:, :2]
    want = np.take_along_axis(pts, idx[:, :, None], axis=1)
    got = cut_segments(vals, xy)
    assert 1000 < len(got) < 4000
    assert np.array_equal(got, want)


def test_mixed_cells_marked_as_the_vectorised_form():
    from pfem2x.physics.flow._kernels import mark_mixed_cells

    rng = np.random.default_rng(6)
    phi = rng.standard_normal(500)
    phi[rng.random(500) < 0.1] = 0.0
    dofmap = rng.integers(0, 500, (700, 3)).astype(np.int32)
    hc = (phi >= 0.0)[dofmap]
    want = np.zeros(500)
    want[dofmap[hc.any(axis=1) & ~hc.all(axis=1)]] = 1.0
    got = np.zeros(500)
    mark_mixed_cells(phi, dofmap, got)
    assert 0 < want.sum() < 500 and np.array_equal(got, want)


def test_particle_fraction_as_the_vectorised_form():
    """Cells' mean particle phase (bincount's sums), empty cells the nodal mean."""
    from pfem2x.physics.flow._kernels import particle_fraction_kernel

    rng = np.random.default_rng(7)
    n_owned, nodes = 300, 200
    cells = rng.integers(0, n_owned + 20, 2000).astype(np.int32)  # some past the owned
    cells[np.isin(cells, [3, 17, 42])] = 5  # empty cells
    phase = (rng.random(2000) < 0.4).astype(float)
    nodal = rng.random(nodes)
    dofmap = rng.integers(0, nodes, (n_owned + 20, 3)).astype(np.int32)
    n = np.bincount(cells, minlength=n_owned)[:n_owned]
    heavy = np.bincount(cells, weights=phase, minlength=n_owned)
    mean = nodal[dofmap[:n_owned]].mean(axis=1)
    want = np.where(n > 0, heavy[:n_owned] / np.maximum(n, 1), mean)
    got = particle_fraction_kernel(cells, phase, n_owned, nodal, dofmap)
    assert (n == 0).sum() >= 3 and np.array_equal(got, want)
