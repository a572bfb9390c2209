"""Population control: bounds per cell, values of new particles, most crowded removed first."""

import numpy as np
import pytest

from pfem2x import compat
from pfem2x.compat import MPI, dolfinx
from pfem2x.mesh import build_mesh
from pfem2x.particles import Cloud, rebalance, seed_cells


def _lin(x):
    return 0.3 - 1.2 * x[:, 0] + 2.5 * x[:, 1]


@pytest.mark.mpi
def test_rebalance_bounds_and_linear_field(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [8, 8])
    cl = Cloud(d, {"T": (), "v": (2,)})
    # uneven population: crowded left half, sparse right half
    seed_cells(cl, 20, seed=1, region=lambda x: x[:, 0] < 0.5)
    seed_cells(cl, 2, seed=2, region=lambda x: x[:, 0] >= 0.5)
    cl["T"] = _lin(cl.x)
    cl["v"] = np.stack([_lin(cl.x), 2 * cl.x[:, 0]], axis=1)
    counts = cl.counts_per_cell()
    assert counts.max() > 12 and counts.min() < 6
    st = rebalance(cl, 6, 12, seed=3)
    counts = cl.counts_per_cell()
    # reduce before asserting: a rank failing alone would leave the other in a collective
    lo = comm.allreduce(int(counts.min()), op=MPI.MIN)
    hi = comm.allreduce(int(counts.max()), op=MPI.MAX)
    assert lo >= 6 and hi <= 12
    added = comm.allreduce(st.added, op=MPI.SUM)
    removed = comm.allreduce(st.removed, op=MPI.SUM)
    assert added > 0 and removed > 0
    assert comm.allreduce(int(cl.check()), op=MPI.MIN)
    err = max(
        np.abs(cl["T"] - _lin(cl.x)).max(initial=0.0),
        np.abs(cl["v"][:, 0] - _lin(cl.x)).max(initial=0.0),
        np.abs(cl["v"][:, 1] - 2 * cl.x[:, 0]).max(initial=0.0),
    )
    assert comm.allreduce(err, op=MPI.MAX) < 1e-10
    assert comm.allreduce(st.unfilled, op=MPI.SUM) == 0


def test_removal_takes_most_crowded(comm):
    d = build_mesh(comm, "interval", [0.0, 1.0], [1])
    cl = Cloud(d, {"T": ()})
    x = np.array([[0.1], [0.5], [0.51], [0.9]])
    cl.append(x, np.zeros(4, dtype=np.int32), {"T": np.arange(4.0)})
    rebalance(cl, 1, 3)
    kept = np.sort(cl.x[:, 0])
    assert len(kept) == 3
    assert 0.1 in kept and 0.9 in kept  # one of the close pair went


def test_empty_cell_filled_from_neighbours(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [4, 4])
    cl = Cloud(d, {"T": ()})
    seed_cells(cl, 8, seed=4, region=lambda x: np.abs(x[:, 0] - 0.6) > 0.3)
    cl["T"] = _lin(cl.x)
    st = rebalance(cl, 4, 0, seed=5)
    assert (cl.counts_per_cell() >= 4).all()
    assert st.added > 0
    # patch fits from facet neighbours reproduce the linear field where they exist
    fit = np.allclose(cl["T"], _lin(cl.x), atol=1e-10)
    assert fit or st.from_idw + st.unfilled > 0


def _collinear_cloud(d):
    """Three nearly collinear particles with values 0, 1, 0 on the one-cell-square mesh ``d``."""
    cl = Cloud(d, {"T": ()})
    if d.mesh.topology.index_map(2).size_local:
        x = np.array([[0.2, 0.1], [0.5, 0.101], [0.8, 0.1]])
        c = cl.pmesh.locate_owned_bbtree(x)
        own = c >= 0
        cl.append(x[own], c[own], {"T": np.array([0.0, 1.0, 0.0])[own]})
    return cl


def test_new_values_stay_near_their_samples(comm):
    """Three nearly collinear particles with noisy values: no wild extrapolation.

    The linear fit through (0.2, 0.1), (0.5, 0.101), (0.8, 0.1) with values
    0, 1, 0 has a slope of ~1000 across the line; a new particle placed far
    from it used to get a value of hundreds (seen as FLIP velocities of 1000
    in Rayleigh-Taylor at Courant 2). New values stay within one range of
    the samples on either side.
    """
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [1, 1])
    cl = _collinear_cloud(d)
    n0 = cl.global_count()
    assert n0 == 3
    st = rebalance(cl, 4, 0, seed=1)
    assert comm.allreduce(st.added, op=MPI.SUM) > 0
    t = cl["T"]
    lo = comm.allreduce(t.min() if cl.n else np.inf, op=MPI.MIN)
    hi = comm.allreduce(t.max() if cl.n else -np.inf, op=MPI.MAX)
    assert -1.0 - 1e-12 <= lo and hi <= 2.0 + 1e-12, (lo, hi)


@pytest.mark.mpi
def test_mesh_values_with_and_without_the_cell_deviation(comm):
    """``mesh_fields``: a new particle gets f(x) (+ its cell's mean deviation from f).

    With one deviation per cell the new values are exact: f + that deviation with
    ``mesh_deviation``, f without; with noisy deviations they stay within the range
    of the deviations.
    """
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [6, 6])
    V = compat.function_space(d.mesh, 1)
    f = dolfinx.fem.Function(V)
    f.interpolate(lambda x: 0.3 - 1.2 * x[0] + 2.5 * x[1])
    cl = Cloud(d, {"T": ()})
    seed_cells(cl, 2, seed=3)
    cell_dev = 0.05 * (cl.cells % 7)
    cl["T"] = _lin(cl.x) + cell_dev
    st = rebalance(cl, 5, 0, seed=2, mesh_fields={"T": f}, mesh_deviation=True)
    assert comm.allreduce(st.added, op=MPI.SUM) > 0
    err = np.abs(cl["T"] - _lin(cl.x) - 0.05 * (cl.cells % 7)).max(initial=0.0)
    assert comm.allreduce(err, op=MPI.MAX) < 1e-12
    # without the deviation: the old particles keep theirs, the new ones have none
    rebalance(cl, 8, 0, seed=3, mesh_fields={"T": f})
    r = cl["T"] - _lin(cl.x)
    new = np.abs(r) < 1e-12
    err = np.abs(r[~new] - 0.05 * (cl.cells[~new] % 7)).max(initial=0.0)
    assert comm.allreduce(err, op=MPI.MAX) < 1e-12
    assert comm.allreduce(int(new.sum()), op=MPI.SUM) >= comm.allreduce(cl.n, op=MPI.SUM) // 4
    # noisy deviations: new values within the deviations' range
    cl = Cloud(d, {"T": ()})
    seed_cells(cl, 2, seed=4)
    dev = np.random.default_rng(comm.rank).uniform(-0.5, 0.5, cl.n)
    cl["T"] = _lin(cl.x) + dev
    rebalance(cl, 5, 0, seed=2, mesh_fields={"T": f}, mesh_deviation=True)
    r = cl["T"] - _lin(cl.x)
    lo = comm.allreduce(r.min(initial=np.inf), op=MPI.MIN)
    hi = comm.allreduce(r.max(initial=-np.inf), op=MPI.MAX)
    assert -0.5 - 1e-12 <= lo and hi <= 0.5 + 1e-12, (lo, hi)


@pytest.mark.parametrize("deviation", [False, True])
def test_mesh_values_bound_collinear_samples(comm, deviation):
    """The collinear samples (0, 1, 0) about f = 0: new values within [0, 1]."""
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [1, 1])
    f = dolfinx.fem.Function(compat.function_space(d.mesh, 1))
    cl = _collinear_cloud(d)
    rebalance(cl, 4, 0, seed=1, mesh_fields={"T": f}, mesh_deviation=deviation)
    t = cl["T"]
    lo = comm.allreduce(t.min(initial=np.inf), op=MPI.MIN)
    hi = comm.allreduce(t.max(initial=-np.inf), op=MPI.MAX)
    assert 0.0 <= lo and hi <= 1.0, (lo, hi)


def _twin_clouds():
    """The mesh (6 x 6) and two equal clouds of 5 particles a cell with fields ``T``, ``v``."""
    d = build_mesh(MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [6, 6])
    clouds = [Cloud(d, {"T": (), "v": (2,)}) for _ in range(2)]
    for cl in clouds:
        seed_cells(cl, 5, seed=4)
        cl["T"] = np.arange(cl.n, dtype=float)
        cl["v"] = cl.x[:, ::-1]
    return d, clouds


def test_replace_sorted_is_remove_append_sort():
    """One permutation gives the storage of remove, append and sort_by_cell in turn."""
    d, clouds = _twin_clouds()
    for cl in clouds:
        cl.x[:] = cl.x[::-1].copy()  # unsorted storage (cells follow)
        cl.cells[:] = cl.cells[::-1].copy()
    n = clouds[0].n
    rng = np.random.default_rng(2)
    remove = rng.random(n) < 0.3
    new = Cloud(d, {"T": (), "v": (2,)})
    seed_cells(new, 2, seed=9)
    vals = {"T": -1.0 - np.arange(new.n), "v": new.x.copy()}
    a, b = clouds
    assert a.remove(remove) == remove.sum()
    a.append(new.x, new.cells, vals)
    off_a = a.sort_by_cell()
    assert b.replace_sorted(remove, new.x, new.cells, vals) == (remove.sum(), new.n)
    assert np.array_equal(off_a, b.cell_offsets())
    assert np.array_equal(a.x, b.x) and np.array_equal(a.cells, b.cells)
    for name in ("T", "v"):
        assert np.array_equal(a.field(name), b.field(name))
    assert b.check()


def test_restore_is_remove_all_and_append_of_the_saved():
    """``restore(save())`` gives back the saved particles as remove-all and append would.

    Between the two the cloud is changed every way a pass changes it (moved, thinned,
    grown past its capacity, a hidden work field added); the saved arrays become its
    storage when the capacity is unchanged, and a second save re-uses the arrays the
    restore replaced (no new storage).
    """
    d = build_mesh(MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [6, 6])
    for grow in (False, True):
        cl = Cloud(d, {"T": (), "v": (2,)})
        seed_cells(cl, 5, seed=4)
        cl["T"] = np.arange(cl.n, dtype=float)
        cl["v"] = cl.x[:, ::-1]
        ref = cl.extract()
        saved = cl.save()
        assert set(saved["arrays"]) == {"__x", "__c", "T", "v"}
        cl.x[:] = 0.5
        cl.field("T")[:] = -1.0
        cl.remove(np.arange(cl.n) % 3 == 0)
        cl.add_field("_work", (2,), value=7.0)
        if grow:
            more = Cloud(d, {"T": (), "v": (2,)})
            seed_cells(more, 12, seed=5)
            cl.append(more.x, more.cells, {"T": more["T"]})
        cap = cl.capacity
        kept = saved["arrays"]["__x"]
        replaced = {id(cl._x), id(cl._c), id(cl._f["T"]), id(cl._f["v"])}
        cl.restore(saved)
        assert cl.n == len(ref["__x"]) and cl.capacity == cap
        assert np.array_equal(cl.x, ref["__x"]) and np.array_equal(cl.cells, ref["__c"])
        for name in ("T", "v"):
            assert np.array_equal(cl.field2d(name), ref[name])
        assert not cl.field("_work").any()  # a hidden field: zero, as append leaves it
        assert (cl._x is kept) != grow  # swapped in, or copied into a grown storage
        assert cl.check()
        again = cl.save()
        if not grow:  # the next save copies into the arrays the restore replaced
            assert {id(a) for a in again["arrays"].values()} == replaced


def test_save_with_drop_is_save_then_remove():
    """``save(drop)``: the cloud as ``remove(drop)`` leaves it; the restore gives back all."""
    _, clouds = _twin_clouds()
    for cl in clouds:
        cl.add_field("_work", (), value=3.0)
    a, b = clouds
    drop = np.arange(a.n) % 3 == 1
    ref = a.extract()
    saved_a = a.save()
    a.remove(drop)
    held = b._x
    saved_b = b.save(drop)
    assert saved_b["arrays"]["__x"] is held  # the storage itself, not a copy
    assert b.n == a.n and np.array_equal(b.x, a.x) and np.array_equal(b.cells, a.cells)
    for name in ("T", "v", "_work"):
        assert np.array_equal(b.field2d(name), a.field2d(name))
    a.restore(saved_a)
    b.restore(saved_b)
    for cl in (a, b):
        assert np.array_equal(cl.x, ref["__x"]) and np.array_equal(cl.cells, ref["__c"])
        for name in ("T", "v"):
            assert np.array_equal(cl.field2d(name), ref[name])
        assert cl.check()
    assert b.save(np.zeros(b.n, dtype=bool))["arrays"]["__x"] is not b._x  # nothing dropped


@pytest.mark.mpi
def test_value_table_rows_the_kernel_reads(comm):
    """The new particles' values from the table of the rows read equal those of the full table."""
    from pfem2x.particles import _kernels as K
    from pfem2x.particles.population import _packed_fields

    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [12, 12])
    cl = Cloud(d, {"T": (), "v": (2,)})
    rng = np.random.default_rng(5)
    seed_cells(cl, 6, seed=5)
    cl.remove(rng.random(cl.n) < 0.4)  # short cells, some empty, all over the mesh
    cl["T"] = np.sin(3 * cl.x[:, 0]) + cl.x[:, 1] ** 2
    cl["v"] = rng.random((cl.n, 2))
    pm = cl.pmesh
    order, offsets = K.counting_sort(cl.cells, pm.n_cells)
    plan = K.population_plan(offsets, pm.n_owned, 5, 0, np.zeros(0, dtype=bool))
    names = cl.field_names
    full = np.concatenate([cl.field2d(nm) for nm in names], axis=1)
    rows = _packed_fields(cl, names, order, offsets, plan)
    args = (order, offsets, plan, pm.keys, np.uint64(7), pm.coords, pm.nbr, True, 8)
    a = K.population_add(cl.x, full, *args)
    b = K.population_add(cl.x, rows, *args)
    added = comm.allreduce(len(a[0]), op=MPI.SUM)
    same = all(np.array_equal(p, q) for p, q in zip(a, b, strict=True))
    assert added > 0 and comm.allreduce(same, op=MPI.LAND)
