"""Particles ↔ P1: projection to nodes, interpolation and increments to particles.

Projection methods (per node ``i``, particles ``p`` of the cells around it,
weights ``w_p = N_i(x_p)``):

``"average"``
    ``T_i = sum w_p T_p / sum w_p`` (the paper's / Kratos' weighted average);
    reproduces constants, error ``O(h)`` at boundaries and where the
    particles are unevenly spread.
``"linear"``
    Weighted least-squares fit ``T ≈ a + b·(x - x_i)`` over the same
    particles, ``T_i = a``: reproduces linear fields exactly. Falls back to
    the average where the fit is ill posed: fewer than ``gdim+1`` particles,
    a nearly degenerate spread (``det(C)^(1/g) < min_spread h²`` with ``C``
    the weighted covariance of the positions) or a node farther than
    ``max_extrap`` Mahalanobis radii from the particle centroid.

Nodes no particle reaches keep their previous value (``empty="keep"``) or
take the mean of filled nodes of the cells around them
(``empty="neighbours"``; still-empty nodes keep their value).
Parallel: the per-node moments are summed over ranks (reverse scatter with
add, then forward), so every rank computes identical nodal values.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.particles import _kernels as K
from pfem2x.particles.advect import nodal_values
from pfem2x.particles.cloud import Cloud

__all__ = [
    "ProjectionStats",
    "add_increment",
    "evaluate",
    "interpolate",
    "project",
    "project_fields",
]


@dataclass
class ProjectionStats:
    """Global counts of one projection.

    Attributes
    ----------
    nodes:
        Owned P1 nodes over all ranks.
    empty:
        Nodes no particle reached (value kept or filled from neighbours).
    fallback:
        Nodes where ``"linear"`` fell back to the average.
    """

    nodes: int
    empty: int
    fallback: int


def _target_array(pm: Any, target: Any, k: int) -> np.ndarray:
    if hasattr(target, "x") and hasattr(target, "function_space"):
        a = nodal_values(pm, target, k)  # validates numbering
        return np.asarray(target.x.array).reshape(-1, k)[: a.shape[0]]
    a = np.asarray(target)
    if a.dtype != np.float64 or a.shape[0] < pm.n_dofs:
        raise ValueError("target must be a P1 Function or a float64 (ndofs, k) array")
    return a.reshape(a.shape[0], k)


def project(
    cloud: Cloud,
    name: str,
    target: Any,
    method: str = "linear",
    empty: str = "keep",
    min_spread: float = 1e-3,
    max_extrap: float = 6.0,
) -> ProjectionStats:
    """Project particle field ``name`` onto the P1 ``target`` (collective).

    Parameters
    ----------
    cloud:
        The particles.
    name:
        A scalar or vector particle field.
    target:
        A P1 Function with as many components as the field (or a nodal array
        ``(ndofs, k)``); overwritten at every node a particle reaches,
        ghost entries included.
    method:
        ``"linear"`` (default) or ``"average"``, see the module docstring.
    empty:
        ``"keep"`` or ``"neighbours"``: what nodes without particles get.
    min_spread, max_extrap:
        Well-posedness limits of the linear fit.

    Returns
    -------
    ProjectionStats
    """
    _check_rules(method, empty)
    pm = cloud.pmesh
    vals = cloud.field2d(name)
    k = vals.shape[1]
    g = pm.gdim
    linear = method == "linear"
    ncol = _columns(g, k, linear)
    vec = _work_vector(pm, ncol)
    acc = np.asarray(vec.array).reshape(-1, ncol)
    acc[:] = 0.0
    K.project_accumulate(cloud.x, cloud.cells, vals, pm.arrays, acc, linear)
    compat.scatter_reverse_add(vec)
    compat.scatter_forward(vec)
    return _solve(cloud, acc, k, linear, target, empty, min_spread, max_extrap)


def project_fields(
    cloud: Cloud,
    specs: Sequence[tuple[str, Any, str]],
    empty: str = "keep",
    min_spread: float = 1e-3,
    max_extrap: float = 6.0,
) -> list[ProjectionStats]:
    """:func:`project` of several fields, in one pass over the particles where it can.

    ``specs``: ``(name, target, method)`` per field. Every target gets the values
    :func:`project` gives it, to the bit. One ``"linear"`` field of one or two
    components and any ``"average"`` fields on 2D triangles share one pass over the
    particles and one exchange of the moments (the flow's velocity, phase and
    level set: about half the time of three projections); any other set is
    projected field by field. Collective.

    Returns
    -------
    list of ProjectionStats
        One per field, in the order of ``specs``.
    """
    for _, _, method in specs:
        _check_rules(method, empty)
    pm = cloud.pmesh
    lin = [i for i, sp in enumerate(specs) if sp[2] == "linear"]
    k_lin = cloud.field2d(specs[lin[0]][0]).shape[1] if len(lin) == 1 else 0
    if not (pm.gdim == 2 and pm.arrays.dofs.shape[1] == 3 and 1 <= k_lin <= 2 and len(specs) > 1):
        return [project(cloud, n, t, m, empty, min_spread, max_extrap) for n, t, m in specs]
    avg = [i for i in range(len(specs)) if i != lin[0]]
    arrays = tuple(np.ascontiguousarray(cloud.field2d(specs[i][0])) for i in avg)
    widths = [a.shape[1] for a in arrays]
    n_lin = _columns(2, k_lin, True)
    ncol = n_lin + sum(widths)
    vec = _work_vector(pm, ncol)
    acc = np.asarray(vec.array).reshape(-1, ncol)
    acc[:] = 0.0
    lin_vals = cloud.field2d(specs[lin[0]][0])
    K.project_accumulate_tri_many(cloud.x, cloud.cells, lin_vals, arrays, pm.arrays, acc)
    compat.scatter_reverse_add(vec)
    compat.scatter_forward(vec)
    out: list[Any] = [None] * len(specs)
    target = specs[lin[0]][1]
    own = np.ascontiguousarray(acc[:, :n_lin])
    out[lin[0]] = _solve(cloud, own, k_lin, True, target, empty, min_spread, max_extrap)
    o = n_lin
    for i, kf in zip(avg, widths, strict=True):
        own = np.concatenate([acc[:, :1], acc[:, o : o + kf]], axis=1)
        out[i] = _solve(cloud, own, kf, False, specs[i][1], empty, min_spread, max_extrap)
        o += kf
    return out


def _check_rules(method: str, empty: str) -> None:
    if method not in ("linear", "average"):
        raise ValueError(f"unknown projection method {method!r}")
    if empty not in ("keep", "neighbours"):
        raise ValueError(f"unknown empty-node rule {empty!r}")


def _columns(g: int, k: int, linear: bool) -> int:
    """The moments' columns of a projection of ``k`` components (:func:`K.project_accumulate`)."""
    return (3 + g + g * (g + 1) // 2 + k * (1 + g)) if linear else 1 + k


def _solve(
    cloud: Cloud,
    acc: np.ndarray,
    k: int,
    linear: bool,
    target: Any,
    empty: str,
    min_spread: float,
    max_extrap: float,
) -> ProjectionStats:
    """The nodal values from the summed moments ``acc`` into ``target`` (collective)."""
    pm = cloud.pmesh
    g = pm.gdim
    nd = acc.shape[0]
    filled = np.zeros(nd, dtype=bool)
    fb = np.zeros(nd, dtype=bool)
    tgt = _target_array(pm, target, k)
    # the kernel writes the filled rows only: straight into a C-contiguous target
    direct = tgt[:nd].flags.c_contiguous
    out = tgt[:nd] if direct else np.zeros((nd, k))
    K.project_solve(acc, g, k, linear, out, filled, fb, float(min_spread), float(max_extrap))
    if not direct:
        tgt[:nd][filled] = out[filled]
    # one reduction for the statistics and the question whether any node is empty
    own = pm.n_dofs_owned
    empty_here = ~filled
    counts = np.array(
        [own, int(empty_here[:own].sum()), int(fb[:own].sum()), int(empty_here.sum())]
    )
    counts = cloud.comm.allreduce(counts, op=MPI.SUM)
    if empty == "neighbours" and counts[3]:
        vec2 = _work_vector(pm, 1 + k, "fill")
        a2 = np.asarray(vec2.array).reshape(-1, 1 + k)
        a2[:] = 0.0
        K.neighbour_fill_accumulate(pm.dofs, pm.n_owned, filled, np.ascontiguousarray(tgt[:nd]), a2)
        compat.scatter_reverse_add(vec2)
        compat.scatter_forward(vec2)
        fill = (~filled) & (a2[:, 0] > 0)
        tgt[:nd][fill] = a2[fill, 1:] / a2[fill, :1]
    return ProjectionStats(int(counts[0]), int(counts[1]), int(counts[2]))


def _work_vector(pm: Any, ncol: int, tag: str = "acc") -> Any:
    """A cached distributed work vector per particle mesh (created collectively once)."""
    cache = pm.__dict__.setdefault("_work_vectors", {})
    key = (tag, ncol)
    if key not in cache:
        cache[key] = compat.la_vector(pm.dof_index_map, ncol)
    return cache[key]


def evaluate(cloud: Cloud, f: Any, index: np.ndarray | None = None) -> np.ndarray:
    """Values of a P1 Function / nodal array at the particles: ``(n,)`` or ``(n, k)``.

    ``index``: only at these particles (then ``(len(index),)`` or ``(len(index), k)``).
    """
    pm = cloud.pmesh
    a = nodal_values(pm, f)
    x, cells = (cloud.x, cloud.cells) if index is None else (cloud.x[index], cloud.cells[index])
    v = K.evaluate_p1(x, cells, a, pm.arrays)
    return v[:, 0] if a.shape[1] == 1 else v


def interpolate(cloud: Cloud, name: str, f: Any) -> None:
    """Set particle field ``name`` to the P1 field ``f`` at the particles (initialisation only)."""
    v = evaluate(cloud, f)
    if name not in cloud:
        cloud.add_field(name, v.shape[1:] if v.ndim > 1 else ())
    cloud.field(name)[...] = v


def add_increment(cloud: Cloud, name: str, delta: Any, scale: float = 1.0) -> None:
    """Add ``scale * delta(x_p)`` (a P1 increment) to particle field ``name`` (step 5).

    The particle values are never overwritten, so their sub-cell detail survives.
    """
    v = evaluate(cloud, delta)
    cloud.field(name)[...] += v if scale == 1.0 else scale * v


def _eval_at(pm: Any, f: Any, x: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """P1 field ``f`` at points ``x`` in local ``cells``: ``(m, k)``."""
    a = nodal_values(pm, f)
    return K.evaluate_p1(np.ascontiguousarray(x), cells, a, pm.arrays)
