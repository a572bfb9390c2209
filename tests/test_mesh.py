"""Meshes and the cached geometry table (serial and mpirun -n 2)."""

from pathlib import Path

import numpy as np
import pytest

from pfem2x.compat import MPI
from pfem2x.mesh import MeshError, build_mesh, geometry_table

MESHES = Path(__file__).resolve().parent.parent / "meshes"

CASES = [
    ("interval", [[-6.0], [6.0]], [30]),
    ("rectangle", [[0.0, 0.0], [2.0, 1.0]], [8, 4]),
    ("box", [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]], [3, 3, 3]),
]


def _volume(domain):
    t = domain.table
    return domain.comm.allreduce(t.volume[: t.num_cells_owned].sum(), op=MPI.SUM)


@pytest.mark.mpi
@pytest.mark.parametrize("kind,bounds,cells", CASES)
def test_geometry_table(kind, bounds, cells):
    d = build_mesh(MPI.COMM_WORLD, kind, bounds, cells)
    t = d.table
    assert t is geometry_table(d.mesh)  # cached
    assert _volume(d) == pytest.approx(np.prod(np.subtract(bounds[1], bounds[0])))
    np.testing.assert_allclose(d.bounds, bounds)
    # Barycentric coordinates of the vertices through the inverse map are the identity.
    for i in range(t.tdim + 1):
        lam = np.einsum("cij,cj->ci", t.inv_map, t.coords[:, i] - t.origin)
        full = np.column_stack([1 - lam.sum(axis=1), lam])
        np.testing.assert_allclose(
            full, np.tile(np.eye(t.tdim + 1)[i], (t.num_cells, 1)), atol=1e-12
        )
    # The neighbour across facet i shares every vertex but i, and is unique.
    c, i = np.nonzero(t.neighbours >= 0)
    nb = t.neighbours[c, i]
    for cc, ii, nn in zip(c[:200], i[:200], nb[:200], strict=True):
        shared = set(t.vertices[cc]) - {t.vertices[cc, ii]}
        assert shared <= set(t.vertices[nn])
        assert t.vertices[cc, ii] not in set(t.vertices[nn])
    # Exterior facets are exactly the facets on the box boundary.
    bc, bi = np.nonzero(t.neighbours == -1)
    for cc, ii in zip(bc[:200], bi[:200], strict=True):
        fv = np.delete(t.coords[cc], ii, axis=0)
        on = np.isclose(fv, np.asarray(bounds[0])) | np.isclose(fv, np.asarray(bounds[1]))
        assert on.all(axis=0).any(), fv
    if MPI.COMM_WORLD.size == 1:
        assert not (t.neighbours == -2).any()
    assert np.all(t.h >= t.h_edge) and np.all(t.h_edge > 0)


def test_min_h_is_the_grid_spacing():
    d = build_mesh(MPI.COMM_WORLD, "rectangle", [[0, 0], [1, 2]], [10, 40])
    assert d.min_h() == pytest.approx(0.05)


@pytest.mark.mpi
@pytest.mark.parametrize("name,area", [("square.geo", 1.0), ("disk.geo", np.pi)])
def test_gmsh_geo(name, area):
    d = build_mesh(MPI.COMM_WORLD, "gmsh", file=MESHES / name)
    assert d.kind == "gmsh" and d.gdim == 2
    assert _volume(d) == pytest.approx(area, rel=0.01)
    assert d.num_cells_global() > 100


def test_gmsh_errors(tmp_path):
    with pytest.raises(MeshError, match="nope.geo"):
        build_mesh(MPI.COMM_WORLD, "gmsh", file=tmp_path / "nope.geo")
    bad = tmp_path / "bad.geo"
    bad.write_text("Point(1) = {0, 0, 0\n garbage {{\n")
    with pytest.raises(MeshError, match="bad.geo"):
        build_mesh(MPI.COMM_WORLD, "gmsh", file=bad)


def _owned_centroids(domain):
    t = geometry_table(domain.mesh)
    n = domain.mesh.topology.index_map(domain.mesh.topology.dim).size_local
    return t.coords[:n].mean(axis=1)


@pytest.mark.mpi
@pytest.mark.parametrize("diagonal", ["right", "crossed", "left/right"])
def test_partitions_are_deterministic_strips_or_a_grid(diagonal):
    """Default: strips of rows; mesh.partition = [size, 1]: columns. Same cells every time."""
    comm = MPI.COMM_WORLD
    b, cells = [[0.0, 0.0], [2.0, 1.0]], [8, 6]
    rows = build_mesh(comm, "rectangle", b, cells, diagonal=diagonal)
    again = build_mesh(comm, "rectangle", b, cells, diagonal=diagonal)
    cols = build_mesh(comm, "rectangle", b, cells, diagonal=diagonal, partition=[comm.size, 1])
    named_rows = build_mesh(comm, "rectangle", b, cells, diagonal=diagonal, partition="rows")
    named_cols = build_mesh(comm, "rectangle", b, cells, diagonal=diagonal, partition="columns")
    assert np.array_equal(_owned_centroids(named_rows), _owned_centroids(rows))
    assert np.array_equal(_owned_centroids(named_cols), _owned_centroids(cols))
    ya, xa = _owned_centroids(rows)[:, 1], _owned_centroids(cols)[:, 0]
    assert np.array_equal(_owned_centroids(rows), _owned_centroids(again))
    r, s = comm.rank, comm.size
    # each rank's owned cells lie in its own strip (6 rows / 8 columns over `size` ranks)
    assert ya.min() >= np.floor(r * 6 / s) / 6 - 1e-12 and ya.max() <= np.ceil((r + 1) * 6 / s) / 6
    lo, hi = 2.0 * np.floor(r * 8 / s) / 8, 2.0 * np.ceil((r + 1) * 8 / s) / 8
    assert xa.min() >= lo - 1e-12 and xa.max() <= hi + 1e-12
    n_all = comm.allreduce(len(xa), op=MPI.SUM)
    assert n_all == (4 if diagonal == "crossed" else 2) * 48


def test_partition_errors():
    comm = MPI.COMM_WORLD
    with pytest.raises(MeshError, match="mesh.partition"):
        build_mesh(comm, "rectangle", [[0, 0], [1, 1]], [4, 4], partition=[2, comm.size])
    with pytest.raises(MeshError, match="only available for rectangles"):
        build_mesh(comm, "interval", [[0.0], [1.0]], [4], partition=[1, 1])
    with pytest.raises(MeshError, match="only available for rectangles"):
        build_mesh(comm, "interval", [[0.0], [1.0]], [4], partition="columns")
