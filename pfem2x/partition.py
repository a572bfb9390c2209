"""Deterministic cell partitions of the built-in meshes (interval, rectangle, box).

DOLFINx 0.5's SCOTCH partition changes from run to run, so a resumed or
repeated MPI run would continue on another partition. The built-in meshes
are therefore split by a rule of the input cell numbering: contiguous blocks
(for meshes numbered row by row, strips of rows) or, for a rectangle, a
``px x py`` grid of sub-rectangles. Each cell also lists the ranks of its
facet neighbours (its ghost copies).

The rule is policy and lives here; the DOLFINx callback it is wrapped in is
a version shim (:func:`pfem2x.compat.cell_partitioner`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI

__all__ = ["GridOwner", "Owner", "block_partitioner", "owner_blocks", "rectangle_partitioner"]

Owner = Callable[[np.ndarray, int, int], np.ndarray]
"""``owner(g, nparts, total) -> ranks``: the rank of input cells ``g`` (int64) of ``total``."""


def owner_blocks(g: np.ndarray, nparts: int, total: int) -> np.ndarray:
    """Rank of input cells ``g``: contiguous blocks of the input numbering."""
    return (g * nparts // max(total, 1)).astype(np.int32)


class GridOwner:
    """Rank of input cells of a built-in rectangle: a ``px x py`` grid of sub-rectangles.

    DOLFINx numbers a rectangle's cells square by square, row by row (``per_square``
    triangles each), on every version supported here.
    """

    def __init__(self, nx: int, ny: int, per_square: int, px: int, py: int):
        self.nx, self.ny, self.per, self.px, self.py = nx, ny, per_square, px, py

    def __call__(self, g: np.ndarray, nparts: int, total: int) -> np.ndarray:
        s = g // self.per
        i, j = s % self.nx, s // self.nx
        return (i * self.px // self.nx + self.px * (j * self.py // self.ny)).astype(np.int32)


def _destinations(owner: Owner) -> compat.Destinations:
    """The destination rule of :func:`pfem2x.compat.cell_partitioner` for ``owner``.

    Input cell ``g`` goes to ``owner(g, nparts, total)``; with ``ghosting`` its
    row lists that rank first, then the ranks of its facet neighbours.
    """

    def dest(
        comm: MPI.Comm,
        nparts: int,
        n: int,
        links: np.ndarray,
        offsets: np.ndarray,
        ghosting: bool,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        offset = int(comm.exscan(n) or 0)
        total = int(comm.allreduce(n))
        own = owner(offset + np.arange(n, dtype=np.int64), nparts, total)
        if not ghosting:
            return own, None
        links = np.asarray(links, dtype=np.int64)
        offs = np.asarray(offsets, dtype=np.int64)
        nbr = owner(links, nparts, total)
        node = np.repeat(np.arange(n, dtype=np.int64), np.diff(offs))
        ext = nbr != own[node]
        pairs = np.unique(np.stack([node[ext], nbr[ext].astype(np.int64)], axis=1), axis=0)
        pairs = pairs.reshape(-1, 2)
        count = np.bincount(pairs[:, 0], minlength=n) + 1
        o = np.concatenate([[0], np.cumsum(count)]).astype(np.int32)
        data = np.empty(int(o[-1]), dtype=np.int32)
        data[o[:-1]] = own
        k = np.arange(len(pairs)) - np.searchsorted(pairs[:, 0], pairs[:, 0])
        data[o[pairs[:, 0]] + 1 + k] = pairs[:, 1]
        return data, o

    return dest


def block_partitioner(owner: Owner | None = None) -> Any:
    """Deterministic cell partitioner of the built-in meshes, with facet ghosts.

    ``owner(g, nparts, total) -> ranks`` of input cells ``g``; default
    contiguous blocks of the input numbering (for the built-in meshes,
    numbered row by row, strips of rows: one cut of ``nx`` facets between
    neighbouring ranks).
    """
    return compat.cell_partitioner(_destinations(owner or owner_blocks))


def rectangle_partitioner(nx: int, ny: int, diagonal: str, grid: Any = None) -> Any:
    """Partitioner of an ``nx x ny`` rectangle split by ``diagonal``.

    ``grid = [px, py]`` (``px * py`` = ranks): that grid of sub-rectangles;
    default strips of rows (:func:`block_partitioner`).
    """
    owner = None
    if grid is not None:
        per = 4 if diagonal == "crossed" else 2
        owner = GridOwner(int(nx), int(ny), per, int(grid[0]), int(grid[1]))
    return block_partitioner(owner)
