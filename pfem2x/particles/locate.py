"""Point location and the common "where did the particle end up" resolution.

:func:`resolve` turns kernel statuses into actions: bounding-box fallback
for walks that did not converge, deletion at outflow facets, and MPI
migration of particles in ghost cells or beyond the ghost layer. It is
collective; :func:`relocate` uses it after positions were edited by hand,
and :func:`pfem2x.particles.advect.advect` after every kernel pass.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pfem2x.compat import MPI
from pfem2x.particles import _kernels as K
from pfem2x.particles.cloud import Cloud
from pfem2x.particles.migrate import exchange, find_owners
from pfem2x.particles.pmesh import ParticleMesh

__all__ = ["LocateStats", "locate_points", "relocate", "resolve"]

MAXIT = 100000


@dataclass
class LocateStats:
    """Counters of one locate / move call (this rank unless noted).

    Attributes
    ----------
    outflow:
        Particles deleted at outflow facets.
    sent, received:
        Particles that left / arrived by MPI migration.
    fallback:
        Walks that needed the bounding-box tree.
    clamped:
        Particles no rank could locate, pulled back into their last cell.
    rounds:
        Migration rounds (same on every rank).
    substeps:
        Sub-steps taken by the move kernel.
    """

    outflow: int = 0
    sent: int = 0
    received: int = 0
    fallback: int = 0
    clamped: int = 0
    rounds: int = 0
    substeps: int = 0


def locate_points(
    pm: ParticleMesh, x: np.ndarray, guess: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Local cells containing the points ``x`` (no walls, no wrap, nothing moved).

    Walks from ``guess`` (bounding-box tree where no guess, ``-1`` guesses,
    or where the walk fails). Returns ``(cells, owned)``: ``-1`` where the
    point is not in any local cell; ``owned`` tells owned cells.
    """
    x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, pm.gdim)
    n = len(x)
    cells = np.full(n, -1, dtype=np.int32)
    if guess is not None:
        g = np.asarray(guess, dtype=np.int32)
        has = g >= 0
        if has.any():
            xx = x[has].copy()
            c, st, _ = K.locate_many(xx, g[has], pm.arrays_plain, MAXIT)
            moved = np.any(xx != x[has], axis=1)  # a wall projection: not inside
            ok = ((st == K.ST_OK) | (st == K.ST_GHOST)) & ~moved
            sub = np.flatnonzero(has)
            cells[sub[ok]] = c[ok]
    miss = cells < 0
    if miss.any():
        cells[miss] = pm.locate_local_bbtree(x[miss])
    return cells, (cells >= 0) & (cells < pm.n_owned)


def resolve(cloud: Cloud, status: np.ndarray, stats: LocateStats) -> tuple[bool, np.ndarray]:
    """Act on kernel statuses; collective.

    ``status`` (one per particle) as in :mod:`pfem2x.particles._kernels`.
    Deletes outflow particles, tries the bounding-box tree for failed walks,
    migrates ghost/remote particles. Returns ``(more, idx)``: whether any
    rank still has particles to continue and the local indices of particles
    that arrived or were re-located here (so the caller continues them).
    """
    pm = cloud.pmesh
    comm = cloud.comm
    status = np.asarray(status).astype(np.int8, copy=True)
    # bounding-box fallback for failed walks
    fail = np.flatnonzero(status == K.ST_FAIL)
    cont = np.zeros(0, dtype=np.int64)
    if len(fail):
        stats.fallback += len(fail)
        c = pm.locate_local_bbtree(cloud.x[fail])
        own = (c >= 0) & (c < pm.n_owned)
        gh = c >= pm.n_owned
        cloud.cells[fail[own | gh]] = c[own | gh]
        status[fail[own]] = K.ST_OK
        status[fail[gh]] = K.ST_GHOST
        status[fail[c < 0]] = K.ST_REMOTE
        cont = fail[own]
    # outflow deletion (indices shift: translate the ones we keep track of)
    out = status == K.ST_OUTFLOW
    if out.any():
        stats.outflow += int(out.sum())
        keep = np.flatnonzero(~out)
        newpos = np.full(len(status), -1, dtype=np.int64)
        newpos[keep] = np.arange(len(keep))
        cont = newpos[cont]
        cloud.remove(out)
        status = status[keep]
    ghost = np.flatnonzero(status == K.ST_GHOST)
    remote = np.flatnonzero(status == K.ST_REMOTE)
    n_move = len(ghost) + len(remote)
    n_cont = len(cont)
    tot = comm.allreduce(np.array([n_move, n_cont]), op=MPI.SUM) if comm.size > 1 else None
    if comm.size == 1:
        if n_move == 0:
            return n_cont > 0, cont
    elif tot[0] == 0:
        return bool(tot[1] > 0), cont
    stats.rounds += 1
    rank_r, gcell_r = find_owners(pm, cloud.x[remote])
    lost = rank_r < 0
    if lost.any():  # nobody has the point: pull it back into its last cell
        li = remote[lost]
        stats.clamped += len(li)
        xs = cloud.x[li].copy()
        K.clamp_into(xs, cloud.cells[li].copy(), pm.arrays)
        cloud.x[li] = xs
        lc = cloud.cells[li]
        rank_r[lost] = pm.owner_of(lc)
        gcell_r[lost] = pm.global_cell(lc)
    idx = np.concatenate([ghost, remote])
    dest = np.concatenate([pm.owner_of(cloud.cells[ghost]), rank_r])
    gcell = np.concatenate([pm.global_cell(cloud.cells[ghost]), gcell_r])
    stats.sent += int((dest != comm.rank).sum())
    n_before = cloud.n - int((dest != comm.rank).sum())
    moved, cont2 = exchange(cloud, idx, dest, gcell, track=cont)
    stats.received += cloud.n - n_before
    return True, np.union1d(cont2, moved)


def relocate(cloud: Cloud) -> LocateStats:
    """Re-locate every particle after its position was changed by hand; collective.

    Walks from the current cell (walls push back inside, periodic directions
    wrap, outflow deletes), falls back to the bounding-box tree, and migrates
    particles to their owning rank.
    """
    pm = cloud.pmesh
    stats = LocateStats()
    x = cloud.x
    c, st, _ = K.locate_many(x, cloud.cells.copy(), pm.arrays, MAXIT)
    cloud.cells[:] = c
    status = st
    while True:
        more, _ = resolve(cloud, status, stats)
        if not more:
            break
        status = np.zeros(cloud.n, dtype=np.int8)
        status[cloud.cells >= pm.n_owned] = K.ST_GHOST
    cloud.invalidate_order()
    return stats
