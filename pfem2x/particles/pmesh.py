"""Per-mesh arrays the particle kernels walk on (built once per domain + boundary set)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.parallel import rank_boxes
from pfem2x.particles import _kernels as K

__all__ = ["ParticleMesh", "FacetMarker"]

FacetMarker = Callable[[np.ndarray], np.ndarray]
"""A vectorised predicate on facet midpoints ``(n, gdim) -> (n,) bool``."""


class ParticleMesh:
    """Mesh data for particles: geometry, P1 dofs, facet codes, parallel maps.

    Parameters
    ----------
    domain:
        A :class:`pfem2x.mesh.Domain`. Box directions with ``domain.periodic``
        wrap; every other exterior facet is a slip wall unless marked.
    outflow:
        Exterior facets whose midpoint satisfies this predicate delete the
        particles that leave through them (counted).
    inflow:
        Exterior facets marked as inflow (walls for the walk; used by
        :func:`pfem2x.particles.population.seed_inflow`).

    Attributes
    ----------
    nbr, pshift, period:
        Facet codes for the kernels (see :mod:`pfem2x.particles._kernels`).
    arrays:
        The mesh packed for the kernels (:class:`pfem2x.particles._kernels.MeshArrays`).
    arrays_plain:
        The same with periodic and outflow facets as walls (a walk that only
        looks for the cell of a point, never moves it to an image).
    dofs:
        ``(num_cells, tdim+1)`` P1 dof indices per cell (owned + ghost cells).
    inflow_facets:
        ``(num_cells, tdim+1)`` bool.
    """

    def __init__(
        self,
        domain: Any,
        outflow: FacetMarker | None = None,
        inflow: FacetMarker | None = None,
    ) -> None:
        t = domain.table
        self._tree_all: Any = None
        self._tree_owned: Any = None
        self.domain = domain
        self.mesh = domain.mesh
        self.comm: MPI.Comm = domain.mesh.comm
        self.tdim = t.tdim
        self.gdim = t.gdim
        self.n_owned = int(t.num_cells_owned)
        self.n_cells = int(t.num_cells)
        self.origin = np.ascontiguousarray(t.origin, dtype=np.float64)
        self.inv = np.ascontiguousarray(t.inv_map, dtype=np.float64)
        self.coords = np.ascontiguousarray(t.coords, dtype=np.float64)
        self.h = np.ascontiguousarray(t.h, dtype=np.float64)
        self.volume = np.asarray(t.volume, dtype=np.float64)
        self.V = compat.function_space(self.mesh, 1)
        self.dofs = np.ascontiguousarray(compat.dofmap_array(self.V)[: self.n_cells])
        imap = self.V.dofmap.index_map
        self.dof_index_map = imap
        self.n_dofs = int(imap.size_local + imap.num_ghosts)
        self.n_dofs_owned = int(imap.size_local)

        bounds = np.asarray(domain.bounds, dtype=np.float64).reshape(2, -1)
        self.period = np.ascontiguousarray(bounds[1] - bounds[0], dtype=np.float64)
        periodic = tuple(bool(p) for p in domain.periodic)
        self.periodic = periodic
        nbr = np.array(t.neighbours, dtype=np.int32, copy=True)
        pshift = np.zeros(nbr.shape, dtype=np.int8)
        ext = nbr == K.WALL
        mid = self._facet_midpoints()
        self.inflow_facets = np.zeros(nbr.shape, dtype=bool)
        if outflow is not None and ext.any():
            sel = np.zeros(nbr.shape, dtype=bool)
            sel[ext] = np.asarray(outflow(mid[ext]), dtype=bool)
            nbr[sel] = K.OUTFLOW
            ext &= ~sel
        if inflow is not None and ext.any():
            self.inflow_facets[ext] = np.asarray(inflow(mid[ext]), dtype=bool)
        self._setup_periodic(nbr, pshift, ext, bounds, periodic)
        self.nbr = np.ascontiguousarray(nbr)
        self.pshift = np.ascontiguousarray(pshift)
        plain = self.nbr.copy()
        plain[(pshift != 0) | (plain == K.OUTFLOW)] = K.WALL
        self.nbr_plain = np.ascontiguousarray(plain)

        self.arrays = K.MeshArrays(
            self.origin,
            self.inv,
            self.coords,
            self.h,
            self.dofs,
            self.nbr,
            self.pshift,
            self.period,
            self.n_owned,
        )
        self.arrays_plain = self.arrays._replace(
            nbr=self.nbr_plain, pshift=np.zeros_like(self.pshift)
        )

        cmap = self.mesh.topology.index_map(self.tdim)
        self.cell_range = compat.index_map_local_range(cmap)
        self.ghost_owners = compat.index_map_ghost_owners(cmap)
        self.ghost_global = compat.index_map_ghosts(cmap)
        self.keys = np.ascontiguousarray(compat.original_cell_index(self.mesh)[: self.n_cells])
        self.rank_boxes = rank_boxes(self.comm, self.coords[: self.n_owned], self.gdim)

    # ------------------------------------------------------------------ helpers
    def _facet_midpoints(self) -> np.ndarray:
        nv = self.tdim + 1
        s = self.coords.sum(axis=1)  # (cells, gdim)
        if nv == 1:
            return self.coords.copy()
        return (s[:, None, :] - self.coords) / (nv - 1)

    def _setup_periodic(
        self,
        nbr: np.ndarray,
        pshift: np.ndarray,
        ext: np.ndarray,
        bounds: np.ndarray,
        periodic: tuple[bool, ...],
    ) -> None:
        if not any(periodic) or not ext.any():
            return
        nv = self.tdim + 1
        cells, fac = np.nonzero(ext)
        # vertices of each facet: all local vertices except the opposite one
        keep = np.ones((len(cells), nv), dtype=bool)
        keep[np.arange(len(cells)), fac] = False
        fv = self.coords[cells][keep].reshape(len(cells), max(nv - 1, 1), self.gdim)
        mid = fv.mean(axis=1)
        scale = self.h[cells]
        for ax, per in enumerate(periodic):
            if not per:
                continue
            L = self.period[ax]
            tol = 1e-8 * max(L, 1.0)
            for side, sign in ((1, 1), (0, -1)):
                on = np.all(np.abs(fv[:, :, ax] - bounds[side, ax]) < tol, axis=1)
                if not on.any():
                    continue
                img = mid[on].copy()
                # exiting the hi face (sign > 0) re-enters at lo, slightly inside
                img[:, ax] += -sign * L + sign * 1e-6 * scale[on]
                c_img = compat.colliding_cells(self.mesh, self.tree_all(), _pad3(img))
                nbr[cells[on], fac[on]] = np.where(c_img >= 0, c_img, K.REMOTE)
                pshift[cells[on], fac[on]] = sign * (ax + 1)

    def tree_all(self) -> Any:
        """Bounding-box tree over all local cells (owned + ghost), built lazily."""
        if self._tree_all is None:
            self._tree_all = compat.bb_tree(self.mesh)
        return self._tree_all

    def tree_owned(self) -> Any:
        """Bounding-box tree over the owned cells only, built lazily."""
        if self._tree_owned is None:
            self._tree_owned = compat.bb_tree_cells(self.mesh, np.arange(self.n_owned))
        return self._tree_owned

    def locate_owned_bbtree(self, x: np.ndarray) -> np.ndarray:
        """Owned cell containing each point (``-1`` where none) via the bounding-box tree."""
        if len(x) == 0 or self.n_owned == 0:
            return np.full(len(x), -1, dtype=np.int32)
        c = compat.colliding_cells(self.mesh, self.tree_owned(), _pad3(x))
        c[c >= self.n_owned] = -1
        return c

    def locate_local_bbtree(self, x: np.ndarray) -> np.ndarray:
        """Local cell (owned preferred, then ghost) containing each point, ``-1`` where none."""
        c = self.locate_owned_bbtree(x)
        miss = c < 0
        if miss.any() and self.n_cells > self.n_owned:
            c2 = compat.colliding_cells(self.mesh, self.tree_all(), _pad3(x[miss]))
            c[miss] = c2
        return c

    def global_cell(self, cells: np.ndarray) -> np.ndarray:
        """Global index of local cells (owned + ghost)."""
        cells = np.asarray(cells, dtype=np.int64)
        out = cells + self.cell_range[0]
        g = cells >= self.n_owned
        out[g] = self.ghost_global[cells[g] - self.n_owned]
        return out

    def owner_of(self, cells: np.ndarray) -> np.ndarray:
        """Owning rank of local cells."""
        cells = np.asarray(cells, dtype=np.int64)
        out = np.full(len(cells), self.comm.rank, dtype=np.int32)
        g = cells >= self.n_owned
        out[g] = self.ghost_owners[cells[g] - self.n_owned]
        return out


def _pad3(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    out = np.zeros((x.shape[0], 3))
    out[:, : x.shape[1]] = x
    return out
