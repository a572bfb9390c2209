"""MPI helpers shared by the point evaluator and the particle layer.

Row exchanges between all ranks and the "ask every rank whose box holds the
point" look-up pattern. Every function is collective over ``comm`` unless
it says otherwise.
"""

from __future__ import annotations

import numpy as np

from pfem2x.compat import MPI

__all__ = ["alltoallv_rows", "box_requests", "rank_boxes"]


def alltoallv_rows(comm: MPI.Comm, blocks: list[np.ndarray], ncol: int) -> list[np.ndarray]:
    """Send ``blocks[r]`` (``(m_r, ncol)``, sent as float64) to rank ``r``.

    Collective. Returns the blocks received, one ``(k_r, ncol)`` float64
    array per source rank (views into one receive buffer).
    """
    size = comm.size
    counts = np.array([b.shape[0] for b in blocks], dtype=np.int64)
    rcounts = np.empty(size, dtype=np.int64)
    comm.Alltoall(counts, rcounts)
    sbuf = np.zeros((0, ncol))
    if counts.sum():
        sbuf = np.ascontiguousarray(np.concatenate(blocks, axis=0), dtype=np.float64)
    rbuf = np.empty((int(rcounts.sum()), ncol))
    sc = counts * ncol
    rc = rcounts * ncol
    sd = np.concatenate([[0], np.cumsum(sc)[:-1]]).astype(np.int64)
    rd = np.concatenate([[0], np.cumsum(rc)[:-1]]).astype(np.int64)
    comm.Alltoallv([sbuf, (sc, sd), MPI.DOUBLE], [rbuf, (rc, rd), MPI.DOUBLE])
    w = max(ncol, 1)
    return [rbuf[rd[r] // w : (rd[r] + rc[r]) // w] for r in range(size)]


def rank_boxes(comm: MPI.Comm, coords: np.ndarray, gdim: int) -> np.ndarray:
    """Bounding box of every rank's ``coords`` (``(..., gdim)``, e.g. its owned cells' vertices).

    Collective. Returns ``(size, 2, gdim)``: ``[r, 0]`` the lower and ``[r, 1]``
    the upper corner of rank ``r`` (``+inf``/``-inf`` for a rank without points).
    """
    c = np.asarray(coords, dtype=np.float64).reshape(-1, gdim)
    if len(c):
        lo, hi = c.min(axis=0), c.max(axis=0)
    else:
        lo, hi = np.full(gdim, np.inf), np.full(gdim, -np.inf)
    return np.array(comm.allgather(np.stack([lo, hi])))


def box_requests(
    x: np.ndarray, boxes: np.ndarray, pad: float, skip: int | None = None
) -> list[np.ndarray]:
    """Indices of the points ``x (n, gdim)`` inside each rank's box (grown by ``pad``).

    Local. ``boxes`` as from :func:`rank_boxes`; ``skip`` excludes one rank
    (e.g. this one, when the points were already looked up here).
    """
    size = boxes.shape[0]
    if len(x):
        inside = np.all(
            (x[:, None, :] >= boxes[None, :, 0, :] - pad)
            & (x[:, None, :] <= boxes[None, :, 1, :] + pad),
            axis=2,
        )
    else:
        inside = np.zeros((0, size), dtype=bool)
    if skip is not None:
        inside[:, skip] = False
    return [np.flatnonzero(inside[:, r]) for r in range(size)]
