"""Evaluate P1 fields at arbitrary points, in parallel (no Python loop over points).

A point is first looked up in this rank's owned cells (bounding-box tree);
points not found locally are sent to every rank whose owned-cell bounding box
contains them, evaluated there and sent back (the lowest rank that found a
point wins). The lookup is collective over the mesh communicator.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.mesh import Domain
from pfem2x.parallel import alltoallv_rows, box_requests, rank_boxes

__all__ = ["PointEvaluator"]


class PointEvaluator:
    """Locate points in a P1 space's mesh and interpolate nodal values there.

    Parameters
    ----------
    domain:
        The mesh.
    V:
        A scalar P1 space on ``domain.mesh`` (its dofmap is used).
    """

    def __init__(self, domain: Domain, V: Any):
        t = domain.table
        self.domain = domain
        self.comm: MPI.Comm = domain.comm
        self.table = t
        self.gdim = t.gdim
        self.n_owned = int(t.num_cells_owned)
        self.dofs = compat.dofmap_array(V)[: t.num_cells]
        self._tree = (
            compat.bb_tree_cells(domain.mesh, np.arange(self.n_owned, dtype=np.int32))
            if self.n_owned
            else None
        )
        self.rank_boxes = rank_boxes(self.comm, t.coords[: self.n_owned], self.gdim)
        span = float(np.max(t.bbox[1] - t.bbox[0]))
        self.pad = 1e-9 * max(span, 1.0)

    def locate_owned(self, x: np.ndarray) -> np.ndarray:
        """Owned cell containing each point ``x (n, gdim)``, ``-1`` where none (local)."""
        if len(x) == 0 or self._tree is None:
            return np.full(len(x), -1, dtype=np.int32)
        pts = np.zeros((x.shape[0], 3))
        pts[:, : self.gdim] = x
        c = compat.colliding_cells(self.domain.mesh, self._tree, pts)
        c[c >= self.n_owned] = -1
        return c

    def interpolate_in(self, x: np.ndarray, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
        """Values ``(n, k)`` of nodal ``values (ndofs, k)`` at points ``x`` in local ``cells``."""
        t = self.table
        d = x - t.origin[cells]
        lam_r = np.einsum("nij,nj->ni", t.inv_map[cells], d)
        lam = np.concatenate([1.0 - lam_r.sum(axis=1, keepdims=True), lam_r], axis=1)
        return np.einsum("ni,nik->nk", lam, values[self.dofs[cells]])

    def evaluate(self, x: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Interpolate nodal ``values`` (``(ndofs,)`` or ``(ndofs, k)``, ghosts up to date).

        Collective. Returns ``(out, found)``: ``out`` has shape ``(n,)`` or
        ``(n, k)`` (zero where not found) and ``found`` is a bool ``(n,)``.
        """
        x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1, self.gdim)
        scalar = values.ndim == 1
        vals = values.reshape(values.shape[0], -1)
        k = vals.shape[1]
        n = x.shape[0]
        out = np.zeros((n, k))
        cells = self.locate_owned(x)
        found = cells >= 0
        if found.any():
            out[found] = self.interpolate_in(x[found], cells[found], vals)
        if self.comm.size > 1:
            self._remote(x, vals, out, found)
        return (out[:, 0] if scalar else out), found

    def _remote(self, x: np.ndarray, vals: np.ndarray, out: np.ndarray, found: np.ndarray) -> None:
        comm = self.comm
        size, me = comm.size, comm.rank
        k = vals.shape[1]
        miss = np.flatnonzero(~found)
        xm = x[miss]
        req = box_requests(xm, self.rank_boxes, self.pad, skip=me)
        got = alltoallv_rows(comm, [xm[i] for i in req], self.gdim)
        replies = []
        for pts in got:
            rep = np.zeros((pts.shape[0], 1 + k))
            if pts.shape[0]:
                c = self.locate_owned(pts)
                ok = c >= 0
                rep[ok, 0] = 1.0
                if ok.any():
                    rep[ok, 1:] = self.interpolate_in(pts[ok], c[ok], vals)
            replies.append(rep)
        back = alltoallv_rows(comm, replies, 1 + k)
        for r in range(size - 1, -1, -1):  # lowest rank wins
            rep = back[r]
            if rep.shape[0] == 0:
                continue
            ok = rep[:, 0] > 0.5
            idx = miss[req[r][ok]]
            out[idx] = rep[ok, 1:]
            found[idx] = True
