"""Seeding: N uniform random particles per cell, reproducible on any number of ranks."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pfem2x.compat import MPI
from pfem2x.particles import _kernels as K
from pfem2x.particles.cloud import Cloud

__all__ = ["seed_cells", "assign_ids"]


def seed_cells(
    cloud: Cloud,
    per_cell: int,
    seed: int = 0,
    cells: np.ndarray | None = None,
    region: Callable[[np.ndarray], np.ndarray] | None = None,
) -> slice:
    """Add ``per_cell`` particles, uniform in each owned cell (interval, triangle, tet).

    Parameters
    ----------
    cloud:
        The cloud to add to.
    per_cell:
        Particles per cell.
    seed:
        Random seed. Each cell's points depend only on ``seed`` and the
        cell's input (partition-independent) index, so the same particles are
        produced serially and on any number of ranks.
    cells:
        Owned local cells to seed (default all).
    region:
        Optional predicate ``x (n, gdim) -> bool``: only keep particles inside.

    Returns
    -------
    slice
        The new particles.
    """
    pm = cloud.pmesh
    if cells is None:
        cells = np.arange(pm.n_owned, dtype=np.int32)
    cells = np.ascontiguousarray(cells, dtype=np.int32)
    counts = np.full(len(cells), int(per_cell), dtype=np.int64)
    x, c = K.seed_cells(cells, counts, pm.keys[cells], np.uint64(seed), pm.coords)
    if region is not None and len(x):
        keep = np.asarray(region(x), dtype=bool)
        x, c = x[keep], c[keep]
    return cloud.append(x, c)


def assign_ids(cloud: Cloud, name: str = "id", sl: slice | None = None) -> None:
    """Give the particles in ``sl`` (default all) globally unique ids (a float field).

    Ids are consecutive per rank (exclusive scan of the counts), so they are
    unique but depend on the partition.
    """
    sl = sl or slice(0, cloud.n)
    m = len(range(*sl.indices(cloud.n)))
    start = cloud.comm.exscan(m, op=MPI.SUM) or 0
    if cloud.comm.rank == 0:
        start = 0
    if name not in cloud:
        cloud.add_field(name)
    cloud.field(name)[sl] = start + np.arange(m, dtype=np.float64)
