"""The particle cloud: struct of arrays per MPI rank, cell-ordered on demand."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from pfem2x.buffers import copy_into
from pfem2x.compat import MPI
from pfem2x.particles import _kernels as K
from pfem2x.particles.pmesh import FacetMarker, ParticleMesh

__all__ = ["Cloud"]


def _ncomp(shape: Any) -> tuple[int, tuple[int, ...]]:
    if shape is None or shape == () or shape == 1 and not isinstance(shape, tuple):
        return 1, ()
    if isinstance(shape, int):
        return shape, (shape,)
    shape = tuple(int(s) for s in shape)
    if len(shape) != 1:
        raise ValueError(f"particle fields are scalars or vectors, got shape {shape}")
    return shape[0], shape


class Cloud:
    """Particles of one rank: positions, owning local cell and named float fields.

    Parameters
    ----------
    mesh:
        A :class:`pfem2x.mesh.Domain` or an existing :class:`ParticleMesh`.
    fields:
        ``{name: shape}`` with shape ``()`` (scalar) or ``(k,)`` / ``k`` (vector).
    outflow, inflow:
        Facet markers, see :class:`ParticleMesh` (ignored when ``mesh`` is
        already a :class:`ParticleMesh`).
    capacity:
        Initial storage capacity (grows by doubling).

    Notes
    -----
    Between operations every particle lies in a cell owned by this rank.
    Storage is amortised: ``append`` grows by doubling, ``remove`` compacts
    in one pass. :meth:`sort_by_cell` reorders all arrays by cell (a
    counting sort), which makes the move and projection kernels several
    times faster; the cell offsets it leaves are used by the population
    control. A reordering gathers each array into a spare one of the same
    shape and swaps the two (views taken before it, like those taken
    before an ``append`` that grows the storage, no longer belong to the
    cloud); the arrays of removed fields are kept as spares too, so the
    move's work fields cost no fresh memory.
    """

    def __init__(
        self,
        mesh: Any,
        fields: Mapping[str, Any] | None = None,
        outflow: FacetMarker | None = None,
        inflow: FacetMarker | None = None,
        capacity: int = 0,
    ) -> None:
        self.pmesh: ParticleMesh = (
            mesh if isinstance(mesh, ParticleMesh) else ParticleMesh(mesh, outflow, inflow)
        )
        self.gdim = self.pmesh.gdim
        cap = max(int(capacity), 16)
        self._n = 0
        self._x = np.zeros((cap, self.gdim))
        self._c = np.zeros(cap, dtype=np.int32)
        self._f: dict[str, np.ndarray] = {}
        self._shape: dict[str, tuple[int, ...]] = {}
        self._offsets: np.ndarray | None = None
        #: spare storage arrays of the current capacity, by (row width, dtype)
        self._spare: dict[tuple[int, str], list[np.ndarray]] = {}
        for name, shape in (fields or {}).items():
            self.add_field(name, shape)

    # ------------------------------------------------------------------ access
    @property
    def comm(self) -> MPI.Comm:
        """The mesh communicator."""
        return self.pmesh.comm

    @property
    def n(self) -> int:
        """Number of particles on this rank."""
        return self._n

    def __len__(self) -> int:
        return self._n

    @property
    def capacity(self) -> int:
        """Allocated particle slots."""
        return self._x.shape[0]

    @property
    def x(self) -> np.ndarray:
        """Positions ``(n, gdim)`` (a writable view; call :meth:`relocate` after editing)."""
        return self._x[: self._n]

    @property
    def cells(self) -> np.ndarray:
        """Owning local cell of each particle ``(n,)`` (view)."""
        return self._c[: self._n]

    @property
    def field_names(self) -> list[str]:
        """Names of the fields (hidden ``_``-prefixed work fields excluded)."""
        return [k for k in self._f if not k.startswith("_")]

    def field_shape(self, name: str) -> tuple[int, ...]:
        """Shape of one particle's value of ``name``: ``()`` or ``(k,)``."""
        return self._shape[name]

    def field(self, name: str) -> np.ndarray:
        """Values of ``name``: ``(n,)`` for scalars, ``(n, k)`` for vectors (writable view)."""
        a = self._f[name][: self._n]
        return a[:, 0] if self._shape[name] == () else a

    def field2d(self, name: str) -> np.ndarray:
        """Values of ``name`` always as ``(n, k)`` (writable view)."""
        return self._f[name][: self._n]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.field(name)

    def __setitem__(self, name: str, value: Any) -> None:
        if name not in self._f:
            v = np.asarray(value)
            self.add_field(name, v.shape[1:] if v.ndim > 1 else ())
        self.field(name)[...] = value

    def __contains__(self, name: str) -> bool:
        return name in self._f

    def add_field(self, name: str, shape: Any = (), value: float = 0.0) -> None:
        """Add a float field (``shape`` ``()`` or ``(k,)``), filled with ``value``.

        The particles' values are ``value``; storage slots beyond :attr:`n` are
        undefined (every operation writes a slot before it holds a particle).
        """
        k, shp = _ncomp(shape)
        if name in self._f:
            if self._shape[name] != shp:
                raise ValueError(f"field {name!r} exists with shape {self._shape[name]}")
            return
        a = self._spare_array((self.capacity, k), np.float64)
        a[: self._n] = float(value)
        self._f[name] = a
        self._shape[name] = shp

    def remove_field(self, name: str) -> None:
        """Drop a field (no error if absent); its storage is kept as a spare."""
        a = self._f.pop(name, None)
        self._shape.pop(name, None)
        if a is not None:
            self._keep_spare(a)

    def _spare_array(self, shape: tuple[int, ...], dtype: Any) -> np.ndarray:
        """A spare storage array of ``shape`` (rows: the capacity), else a new one."""
        width = shape[1] if len(shape) > 1 else 0
        pool = self._spare.get((width, np.dtype(dtype).str))
        if pool and pool[-1].shape == shape:
            return pool.pop()
        return np.empty(shape, dtype=dtype)

    def _keep_spare(self, a: np.ndarray) -> None:
        """Keep storage array ``a`` (of the current capacity) for re-use."""
        if a.shape[0] == self.capacity:
            width = a.shape[1] if a.ndim > 1 else 0
            pool = self._spare.setdefault((width, a.dtype.str), [])
            if len(pool) < 4:
                pool.append(a)

    # ------------------------------------------------------------------ storage
    def reserve(self, capacity: int) -> None:
        """Make room for at least ``capacity`` particles."""
        if capacity <= self.capacity:
            return
        cap = max(int(capacity), 2 * self.capacity)
        n = self._n
        self._spare.clear()
        x = np.zeros((cap, self.gdim))
        x[:n] = self._x[:n]
        c = np.zeros(cap, dtype=np.int32)
        c[:n] = self._c[:n]
        self._x, self._c = x, c
        for name, a in self._f.items():
            b = np.zeros((cap, a.shape[1]))
            b[:n] = a[:n]
            self._f[name] = b

    def append(
        self,
        x: np.ndarray,
        cells: np.ndarray,
        values: Mapping[str, Any] | None = None,
    ) -> slice:
        """Append particles (positions, owning local cells, optional field values).

        Fields not given are zero. Returns the slice of the new particles.
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.gdim)
        m = x.shape[0]
        n = self._n
        self.reserve(n + m)
        self._x[n : n + m] = x
        self._c[n : n + m] = np.asarray(cells, dtype=np.int32)
        for name, a in self._f.items():
            if values is not None and name in values:
                a[n : n + m] = np.asarray(values[name], dtype=np.float64).reshape(m, a.shape[1])
            else:
                a[n : n + m] = 0.0
        self._n = n + m
        self._offsets = None
        return slice(n, n + m)

    def remove(self, mask: np.ndarray) -> int:
        """Remove the particles where ``mask`` is true; returns how many."""
        mask = np.asarray(mask, dtype=bool)
        if not mask.any():
            return 0
        keep = np.flatnonzero(~mask)
        self._take(keep)
        return int(mask.sum())

    def _take(self, idx: np.ndarray, spare: bool = True) -> None:
        """Keep particles ``idx`` (int64, each index once), in that order.

        Each array is gathered into a spare array of its shape, which then takes
        its place (the old one becomes the spare; ``spare = False``: it is left to
        the caller).
        """
        m = len(idx)
        idx = np.ascontiguousarray(idx, dtype=np.int64)
        x = self._spare_array(self._x.shape, self._x.dtype)
        K.gather_rows(self._x, idx, x)
        if spare:
            self._keep_spare(self._x)
        self._x = x
        c = self._spare_array(self._c.shape, self._c.dtype)
        np.take(self._c, idx, out=c[:m])
        if spare:
            self._keep_spare(self._c)
        self._c = c
        for name, a in self._f.items():
            b = self._spare_array(a.shape, a.dtype)
            K.gather_rows(a, idx, b)
            if spare:
                self._keep_spare(a)
            self._f[name] = b
        self._n = m
        self._offsets = None

    def remove_unordered(self, idx: np.ndarray) -> np.ndarray:
        """Remove particles ``idx`` (unique) by moving particles from the end into the holes.

        Costs ``O(len(idx))`` copies instead of compacting every array; the
        storage order changes. Returns ``newpos`` (``(n_before,)``): the new
        index of every former particle, ``-1`` for the removed ones.
        """
        idx = np.asarray(idx, dtype=np.int64)
        n = self._n
        m = len(idx)
        newpos = np.arange(n, dtype=np.int64)
        if m == 0:
            return newpos
        gone = np.zeros(n, dtype=bool)
        gone[idx] = True
        keep_n = n - m
        src = np.flatnonzero(~gone[keep_n:]) + keep_n  # survivors past the new end
        dst = idx[idx < keep_n]  # holes before it (as many)
        dst.sort()
        self._x[dst] = self._x[src]
        self._c[dst] = self._c[src]
        for a in self._f.values():
            a[dst] = a[src]
        newpos[idx] = -1
        newpos[src] = dst
        self._n = keep_n
        self._offsets = None
        return newpos

    def replace_sorted(
        self,
        remove: np.ndarray,
        x: np.ndarray,
        cells: np.ndarray,
        values: Mapping[str, Any] | None = None,
    ) -> tuple[int, int]:
        """Remove particles, append new ones and sort by cell, permuting the storage once.

        The result is that of :meth:`remove` (``remove`` a mask), :meth:`append`
        and :meth:`sort_by_cell` in turn: in each cell the kept particles in
        their storage order, then the new ones in the order given.

        Returns
        -------
        tuple of int
            Particles removed and added.
        """
        n = self._n
        remove = np.asarray(remove, dtype=bool)
        sl = self.append(x, cells, values)
        keep = np.concatenate([np.flatnonzero(~remove), np.arange(n, self._n)])
        order, offsets = K.counting_sort(self._c[keep], self.pmesh.n_cells)
        self._take(keep[order])
        self._offsets = offsets
        return int(remove.sum()), sl.stop - sl.start

    def extract(
        self, idx: np.ndarray | None = None, into: dict[str, np.ndarray] | None = None
    ) -> dict[str, np.ndarray]:
        """Copies of positions, cells and all fields (hidden ones too) of ``idx`` (all: None).

        Each array is copied once (fancy indexing already copies; a slice is copied).
        ``into``: an earlier extract of all particles, whose arrays take the copies
        where they have room (:func:`copy_into`; no new arrays, no page faults).
        """
        sel = slice(0, self._n) if idx is None else idx
        old = into if idx is None and into is not None else {}

        def take(key: str, a: np.ndarray) -> np.ndarray:
            r = a[sel]
            if key in old:
                return copy_into(r, old[key])
            return r.copy() if np.may_share_memory(r, a) else r

        out = {"__x": take("__x", self._x), "__c": take("__c", self._c)}
        for name, a in self._f.items():
            out[name] = take(name, a)
        return out

    def save(self, drop: np.ndarray | None = None) -> dict[str, Any]:
        """A copy of the particles (positions, cells, visible fields) for :meth:`restore`.

        The copies are storage arrays of the current capacity, taken from the spare
        arrays where there are any (only the particles' rows are copied): a restore
        swaps them in without copying them back, and the arrays it replaces become the
        spares of the next save. Hidden (``_``-prefixed) work fields are not saved.

        ``drop`` (a boolean mask, some of it true): afterwards the cloud holds the
        other particles only, as :meth:`remove` leaves it; the saved arrays are then
        the storage itself, and the kept particles are gathered into spare arrays (one
        gather, no copy).
        """
        n = self._n
        held = {"__x": self._x, "__c": self._c, **{k: self._f[k] for k in self.field_names}}
        if drop is not None and np.any(drop):
            self._take(np.flatnonzero(~np.asarray(drop, dtype=bool)), spare=False)
            return {"n": n, "arrays": held}
        arrays: dict[str, np.ndarray] = {}
        for name, a in held.items():
            b = self._spare_array(a.shape, a.dtype)
            b[:n] = a[:n]
            arrays[name] = b
        return {"n": n, "arrays": arrays}

    def restore(self, saved: Mapping[str, Any]) -> None:
        """Put back the particles of :meth:`save`; the cloud's own are dropped.

        The result is that of :meth:`remove` of every particle and :meth:`append` of the
        saved positions, cells and fields (a field the save does not hold, a hidden one
        among them, is zero). A saved array of the current capacity becomes the storage
        (the one it replaces a spare); one of another capacity (the cloud grew since)
        is copied. The ``saved`` arrays belong to the cloud afterwards.
        """
        n = int(saved["n"])
        arrays = saved["arrays"]
        self.reserve(n)

        def put(old: np.ndarray, new: np.ndarray) -> np.ndarray:
            if new.shape == old.shape and new.dtype == old.dtype:
                self._keep_spare(old)
                return new
            old[:n] = new[:n]
            return old

        self._x = put(self._x, arrays["__x"])
        self._c = put(self._c, arrays["__c"])
        for name, a in self._f.items():
            b = arrays.get(name)
            if b is None:
                a[:n] = 0.0
            else:
                self._f[name] = put(a, b)
        self._n = n
        self._offsets = None

    # ------------------------------------------------------------------ order
    def sort_by_cell(self) -> np.ndarray:
        """Reorder every array by cell (stable counting sort); returns the cell offsets.

        ``offsets[c]:offsets[c+1]`` are the particles of local cell ``c``.
        """
        order, offsets = K.counting_sort(self.cells, self.pmesh.n_cells)
        if not K.is_identity(order):
            self._take(order)
        self._offsets = offsets
        return offsets

    @property
    def is_sorted(self) -> bool:
        """Whether the arrays are in cell order (and the offsets are valid)."""
        return self._offsets is not None

    def invalidate_order(self) -> None:
        """Forget the cell order (called by anything that moves particles)."""
        self._offsets = None

    def cell_offsets(self) -> np.ndarray:
        """Cell offsets of the cell-ordered storage (sorts when needed)."""
        if self._offsets is None:
            return self.sort_by_cell()
        return self._offsets

    def counts_per_cell(self) -> np.ndarray:
        """Number of particles in each owned cell ``(n_owned,)``."""
        return np.bincount(self.cells, minlength=self.pmesh.n_cells)[: self.pmesh.n_owned]

    # ------------------------------------------------------------------ stats
    def global_count(self) -> int:
        """Number of particles over all ranks."""
        return int(self.comm.allreduce(self._n, op=MPI.SUM))

    def bytes_per_particle(self) -> float:
        """Bytes of storage per particle slot (positions, cell, all fields)."""
        b = self._x.itemsize * self.gdim + self._c.itemsize
        for a in self._f.values():
            b += a.itemsize * a.shape[1]
        return float(b)

    def check(self) -> bool:
        """Every particle lies in its (owned) cell within tolerance."""
        pm = self.pmesh
        if self._n == 0:
            return True
        c = self.cells
        if (c < 0).any() or (c >= pm.n_owned).any():
            return False
        return bool(K.contains(self.x, c, pm.arrays, 1e-8).all())

    def items(self) -> Iterable[tuple[str, np.ndarray]]:
        """``(name, values)`` of the public fields."""
        for name in self.field_names:
            yield name, self.field(name)
