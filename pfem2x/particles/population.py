"""Population control (section 4): keep every cell between ``nmin`` and ``nmax`` particles.

* Cells with too many particles lose the most crowded ones first (the
  particle with the smallest nearest-neighbour distance, repeatedly).
  Removing carries no value error beyond the lost sample.
* Cells with too few get new particles at the best of a few random
  candidates (the one farthest from the existing particles). Their values
  come from the neighbouring particles, error ``o(T'' h²)`` (eq. 4.15): a
  linear least-squares fit of the particles of the cell (exact for linear
  fields) when its value stays near their range, else a fit of the cell
  and its facet neighbours, each only up to 6 Mahalanobis radii from its
  points (a new particle placed across a few nearly collinear ones would
  otherwise get an extrapolated value far outside anything near it), else
  their inverse-distance average; only when no particle is near does a mesh
  field (``fallback``) give the value (eq. 4.14), and without one the new
  particle gets 0 (counted as ``unfilled``). Fields given in ``mesh_fields``
  instead take a mesh field's value at the new position (within the cell's
  nodal values: no limit to tune), with ``mesh_deviation`` plus the mean
  deviation of the cell's particles from that field (exact for the field plus a
  constant per cell).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pfem2x.particles import _kernels as K
from pfem2x.particles.cloud import Cloud

__all__ = ["PopulationStats", "rebalance", "seed_inflow"]


@dataclass
class PopulationStats:
    """What one population pass did on this rank.

    Attributes
    ----------
    added, removed:
        Particles created / deleted.
    from_fit, from_idw, from_mesh, unfilled:
        How the new particles got their values.
    """

    added: int = 0
    removed: int = 0
    from_fit: int = 0
    from_idw: int = 0
    from_mesh: int = 0
    unfilled: int = 0


def rebalance(
    cloud: Cloud,
    nmin: int,
    nmax: int = 0,
    seed: int = 0,
    fallback: Mapping[str, Any] | None = None,
    cells: np.ndarray | None = None,
    candidates: int = 8,
    mesh_fields: Mapping[str, Any] | None = None,
    mesh_deviation: bool = False,
) -> PopulationStats:
    """Add / remove particles so each owned cell has ``nmin <= count <= nmax``.

    Parameters
    ----------
    cloud:
        The particles (sorted by cell as a side effect).
    nmin, nmax:
        Bounds per cell (``nmax = 0``: no upper bound).
    seed:
        Random seed of the new positions (vary it between calls, e.g. the
        step number); positions depend on it and the cell's input index only.
    fallback:
        ``{field: P1 Function}`` used for new particles with no particle near.
    cells:
        Optional bool mask over owned cells: only these are touched.
    candidates:
        Random candidate positions tried per new particle.
    mesh_fields:
        ``{field: P1 Function}``: new particles of these fields get the
        function's value at their position.
    mesh_deviation:
        With ``mesh_fields``: plus the mean of ``value - function`` over the
        particles of their cell before the control (none there: nothing added).

    Returns
    -------
    PopulationStats
    """
    pm = cloud.pmesh
    # the cell order by indirection: the storage is permuted once, at the end
    order, offsets = K.counting_sort(cloud.cells, pm.n_cells)
    only = np.zeros(0, dtype=bool) if cells is None else np.asarray(cells, dtype=bool)
    plan = K.population_plan(offsets, pm.n_owned, int(nmin), int(nmax), only)
    stats = PopulationStats()
    if not plan.any():
        cloud.sort_by_cell()
        return stats
    n = cloud.n
    names = cloud.field_names
    widths = [cloud.field2d(nm).shape[1] for nm in names]
    table = _packed_fields(cloud, names, order, offsets, plan)
    nx, ncell, nvals, src = K.population_add(
        cloud.x,
        table,
        order,
        offsets,
        plan,
        pm.keys,
        np.uint64(seed),
        pm.coords,
        pm.nbr,
        bool(names),
        int(candidates),
    )
    if names:
        cloud._keep_spare(table)  # (its pages stay mapped for the next call)
    remove = np.zeros(n, dtype=bool)
    K.population_remove(cloud.x, order, offsets, plan, remove)
    values = _unpacked_fields(nvals, names, widths)
    if names:
        _count_and_fill(cloud, values, src, nx, ncell, fallback, stats)
        for nm, f in (mesh_fields or {}).items():
            if nm in values:
                values[nm][:] = _mesh_values(cloud, nm, f, nx, ncell, mesh_deviation)
    stats.removed, stats.added = cloud.replace_sorted(remove, nx, ncell, values)
    return stats


def _packed_fields(
    cloud: Cloud, names: list[str], order: np.ndarray, offsets: np.ndarray, plan: np.ndarray
) -> np.ndarray:
    """The fields side by side, ``(n, sum of widths)``: the value table of ``population_add``.

    The kernel reads the values of the particles of each cell that gets new particles
    (``plan > 0``) and of its facet neighbours, so only those rows are filled (found
    from the cells' ranges of ``order``, ``offsets``: the counting sort of the cells);
    the others are left as they come (never read). Most cells get none: a few per cent
    of the table's copy. The table is one of the cloud's spare arrays (its capacity
    rows), handed back after use: a new array of that size is new memory each time,
    whose first writes cost three times the copy (400,000 particles).
    """
    if not names:
        return np.zeros((cloud.n, 0))
    pm = cloud.pmesh
    n_plan = len(plan)
    need = plan > 0
    nb = pm.nbr[:n_plan][need].ravel()
    need[nb[(nb >= 0) & (nb < n_plan)]] = True
    cells = np.flatnonzero(need)
    starts, counts = offsets[cells], offsets[cells + 1] - offsets[cells]
    at = np.repeat(starts - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
    rows = order[at]
    fields = [cloud.field2d(nm) for nm in names]
    table = cloud._spare_array((cloud.capacity, sum(f.shape[1] for f in fields)), np.float64)
    o = 0
    for f in fields:
        K.put_rows(f, rows, table, o)
        o += f.shape[1]
    return table


def _unpacked_fields(
    nvals: np.ndarray, names: list[str], widths: list[int]
) -> dict[str, np.ndarray]:
    """Split a value table of :func:`_packed_fields` back into ``{field: (m, width)}`` views."""
    values: dict[str, np.ndarray] = {}
    o = 0
    for nm, w in zip(names, widths, strict=True):
        values[nm] = nvals[:, o : o + w]
        o += w
    return values


def _mesh_values(
    cloud: Cloud, name: str, f: Any, nx: np.ndarray, ncell: np.ndarray, deviation: bool
) -> np.ndarray:
    """``f(x)`` at the new positions, ``deviation``: plus the cell's mean ``value - f(x_p)``."""
    from pfem2x.particles.transfer import _eval_at  # noqa: PLC0415

    pm = cloud.pmesh
    vals = cloud.field2d(name)
    k = vals.shape[1]
    out = _eval_at(pm, f, nx, ncell).reshape(-1, k)
    if deviation:
        dev = vals - _eval_at(pm, f, cloud.x, cloud.cells).reshape(-1, k)
        count = np.bincount(cloud.cells, minlength=pm.n_cells)[ncell]
        for j in range(k):
            sums = np.bincount(cloud.cells, weights=dev[:, j], minlength=pm.n_cells)[ncell]
            out[:, j] += np.divide(sums, count, out=np.zeros(len(nx)), where=count > 0)
    return out


def _count_and_fill(
    cloud: Cloud,
    values: dict[str, np.ndarray],
    src: np.ndarray,
    nx: np.ndarray,
    ncell: np.ndarray,
    fallback: Mapping[str, Any] | None,
    stats: PopulationStats,
) -> None:
    """Count how the new particles got their values; the mesh fills those no particle was near.

    ``src`` per new particle: 1, 2 a least-squares fit, 3 an inverse-distance
    average, 0 no particle near (then ``fallback`` gives the value in place,
    else it stays 0 and counts as unfilled).
    """
    stats.from_fit = int(np.isin(src, (1, 2)).sum())
    stats.from_idw = int((src == 3).sum())
    none = src == 0
    if none.any() and fallback:
        from pfem2x.particles.transfer import _eval_at  # noqa: PLC0415

        for nm, f in fallback.items():
            if nm in values:
                values[nm][none] = _eval_at(cloud.pmesh, f, nx[none], ncell[none]).reshape(
                    int(none.sum()), -1
                )
        stats.from_mesh = int(none.sum())
    else:
        stats.unfilled = int(none.sum())


def seed_inflow(
    cloud: Cloud,
    per_cell: int,
    values: Mapping[str, float | Callable[[np.ndarray], np.ndarray]] | None = None,
    seed: int = 0,
) -> int:
    """Top up the cells touching inflow facets to ``per_cell`` particles (inflow hook).

    Parameters
    ----------
    cloud:
        The particles; inflow facets are marked on its :class:`ParticleMesh`.
    per_cell:
        Target count in inflow cells.
    values:
        ``{field: constant or callable x (m, gdim) -> (m,) / (m, k)}`` for the
        new particles (the inflow boundary condition); other fields are 0.
    seed:
        Random seed (vary it between calls).

    Returns
    -------
    int
        Particles added on this rank.
    """
    pm = cloud.pmesh
    mask = pm.inflow_facets[: pm.n_owned].any(axis=1)
    if not mask.any():
        return 0
    offsets = cloud.sort_by_cell()
    plan = K.population_plan(offsets, pm.n_owned, int(per_cell), 0, mask)
    nx, ncell, _, _ = K.population_add(
        cloud.x,
        np.zeros((cloud.n, 0)),
        np.arange(cloud.n, dtype=np.int64),
        offsets,
        plan,
        pm.keys,
        np.uint64(seed),
        pm.coords,
        pm.nbr,
        False,
        8,
    )
    vals: dict[str, np.ndarray] = {}
    m = len(nx)
    for nm, v in (values or {}).items():
        k = cloud.field2d(nm).shape[1]
        a = np.asarray(v(nx) if callable(v) else v, dtype=np.float64)
        if a.size == m * k and a.ndim >= 1 and a.shape[0] == m:
            a = a.reshape(m, k)
        vals[nm] = np.broadcast_to(a, (m, k)).copy()
    sl = cloud.append(nx, ncell, vals)
    return sl.stop - sl.start
