"""MPI migration: send particles to the rank owning their cell, fields intact.

Two ways to find the destination:

* a particle located in a local *ghost* cell goes to that cell's owner
  (index-map ghost owners), with the cell's global index;
* a particle whose position is known but whose cell is not local is found by
  a collective search: the point is sent to every rank whose owned-cell
  bounding box contains it, those ranks look it up in their owned cells
  (bounding-box tree), and the lowest rank that found it receives the particle.

Everything here is collective over the mesh communicator; in serial it is a
cheap no-op apart from the local look-up.
"""

from __future__ import annotations

import numpy as np

from pfem2x.parallel import alltoallv_rows, box_requests
from pfem2x.particles.cloud import Cloud
from pfem2x.particles.pmesh import ParticleMesh

__all__ = ["exchange", "find_owners"]


def find_owners(pm: ParticleMesh, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Owning rank and global cell of points ``x`` (``-1, -1`` where no rank has them).

    Collective. Ties (points on partition boundaries) go to the lowest rank.
    """
    comm = pm.comm
    n = x.shape[0]
    if comm.size == 1:
        c = pm.locate_owned_bbtree(x)
        rank = np.where(c >= 0, 0, -1).astype(np.int32)
        return rank, np.where(c >= 0, c + pm.cell_range[0], -1).astype(np.int64)
    size = comm.size
    scale = float(np.max(pm.period)) if len(pm.period) else 1.0
    pad = 1e-9 * max(scale, 1.0)
    gd = pm.gdim
    req = box_requests(x, pm.rank_boxes, pad)
    got = alltoallv_rows(comm, [x[i].reshape(-1, gd) for i in req], gd)
    replies = []
    for pts in got:
        c = pm.locate_owned_bbtree(np.ascontiguousarray(pts))
        g = np.where(c >= 0, c + pm.cell_range[0], -1).astype(np.float64)
        replies.append(g.reshape(-1, 1))
    back = alltoallv_rows(comm, replies, 1)
    rank = np.full(n, -1, dtype=np.int32)
    gcell = np.full(n, -1, dtype=np.int64)
    for r in range(size - 1, -1, -1):  # lowest rank wins
        g = back[r][:, 0].astype(np.int64)
        ok = g >= 0
        rank[req[r][ok]] = r
        gcell[req[r][ok]] = g[ok]
    return rank, gcell


def exchange(
    cloud: Cloud,
    idx: np.ndarray,
    dest: np.ndarray,
    gcell: np.ndarray,
    track: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Move particles ``idx`` to ranks ``dest`` into global cells ``gcell``.

    Particles whose destination is this rank stay (their cell is updated);
    the others are removed here (the last particles fill their slots, so
    the storage order changes) and appended on their destination with all
    fields (hidden work fields included). Collective. Returns the indices
    of the particles that arrived or stayed, so a caller can continue
    working on them, and the new indices of the ``track`` particles (those
    that left dropped).
    """
    pm = cloud.pmesh
    comm = cloud.comm
    rank = comm.rank
    idx = np.asarray(idx, dtype=np.int64)
    dest = np.asarray(dest, dtype=np.int32)
    gcell = np.asarray(gcell, dtype=np.int64)
    track = np.zeros(0, dtype=np.int64) if track is None else np.asarray(track, dtype=np.int64)
    stay = dest == rank
    local_c = (gcell[stay] - pm.cell_range[0]).astype(np.int32)
    cloud.cells[idx[stay]] = local_c
    stay_idx = idx[stay]
    go = ~stay
    names = sorted(cloud._f)
    widths = [cloud._f[nm].shape[1] for nm in names]
    gd = cloud.gdim
    ncol = gd + 1 + int(sum(widths))
    blocks = []
    gi = idx[go]
    gdst = dest[go]
    ggc = gcell[go]
    for r in range(comm.size):
        sel = gdst == r
        if r == rank or not sel.any():
            blocks.append(np.zeros((0, ncol)))
            continue
        ii = gi[sel]
        cols = [cloud._x[ii], ggc[sel].astype(np.float64)[:, None]]
        cols += [cloud._f[nm][ii] for nm in names]
        blocks.append(np.concatenate(cols, axis=1))
    got = alltoallv_rows(comm, blocks, ncol)
    newpos = cloud.remove_unordered(np.unique(gi))
    stay_new = newpos[stay_idx]
    tracked = newpos[track]
    tracked = tracked[tracked >= 0]
    rec = np.concatenate(got, axis=0) if got else np.zeros((0, ncol))
    if rec.shape[0]:
        x = rec[:, :gd]
        c = (rec[:, gd].astype(np.int64) - pm.cell_range[0]).astype(np.int32)
        values = {}
        o = gd + 1
        for nm, w in zip(names, widths, strict=True):
            values[nm] = rec[:, o : o + w]
            o += w
        sl = cloud.append(x, c, values)
        arrived = np.arange(sl.start, sl.stop)
    else:
        arrived = np.zeros(0, dtype=np.int64)
    cloud.invalidate_order()
    return np.concatenate([stay_new, arrived]).astype(np.int64), tracked
