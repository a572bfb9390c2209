"""Meshes: structured interval / rectangle / box, gmsh ``.geo`` files, and the
cached per-mesh geometry table the particle layer walks on.

All DOLFINx calls go through :mod:`pfem2x.compat`.
"""

from __future__ import annotations

import os
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.partition import block_partitioner, rectangle_partitioner

__all__ = [
    "Domain",
    "GeometryTable",
    "MeshError",
    "basis_gradients",
    "build_mesh",
    "geometry_table",
    "read_geo",
]


class MeshError(ValueError):
    """A mesh could not be built from the given input (names the file or key)."""


@dataclass
class GeometryTable:
    """Per-mesh arrays for vectorised point location (local cells, owned then ghosts).

    Attributes
    ----------
    tdim, gdim:
        Topological and geometric dimension (affine simplices, ``tdim == gdim``).
    num_cells_owned, num_cells:
        Owned cells and owned + ghost cells on this rank.
    vertices:
        ``(num_cells, tdim+1)`` local P1 vertex (geometry node) indices per cell.
    coords:
        ``(num_cells, tdim+1, gdim)`` vertex coordinates.
    origin:
        ``(num_cells, gdim)`` coordinates of local vertex 0.
    inv_map:
        ``(num_cells, tdim, gdim)`` inverse of the affine map: barycentric
        ``lambda[1:] = inv_map @ (x - origin)``, ``lambda[0] = 1 - sum``.
    neighbours:
        ``(num_cells, tdim+1)`` the cell across the facet opposite local vertex
        ``i``; ``-1`` on the domain boundary, ``-2`` where the neighbour lives
        on another rank (beyond the ghost layer).
    facet_on_boundary:
        ``(num_cells, tdim+1)`` bool, facet lies on the exterior boundary.
    volume:
        ``(num_cells,)`` cell measure.
    h:
        ``(num_cells,)`` cell diameter (longest edge).
    h_edge:
        ``(num_cells,)`` shortest edge: the mesh size H of Courant numbers.
    bbox:
        ``(2, gdim)`` global bounding box of the mesh.
    """

    tdim: int
    gdim: int
    num_cells_owned: int
    num_cells: int
    vertices: np.ndarray
    coords: np.ndarray
    origin: np.ndarray
    inv_map: np.ndarray
    neighbours: np.ndarray
    facet_on_boundary: np.ndarray
    volume: np.ndarray
    h: np.ndarray
    bbox: np.ndarray
    node_coords: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 3)))
    h_edge: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))


_TABLES: weakref.WeakKeyDictionary[Any, GeometryTable] = weakref.WeakKeyDictionary()
_TABLES_BY_ID: dict[int, tuple[Any, GeometryTable]] = {}


def geometry_table(mesh: Any) -> GeometryTable:
    """Return the cached :class:`GeometryTable` of ``mesh`` (built once per mesh)."""
    try:
        return _TABLES[mesh]
    except TypeError:  # not weak-referenceable
        hit = _TABLES_BY_ID.get(id(mesh))
        if hit is not None and hit[0] is mesh:
            return hit[1]
    except KeyError:
        pass
    table = _build_table(mesh)
    try:
        _TABLES[mesh] = table
    except TypeError:
        _TABLES_BY_ID[id(mesh)] = (mesh, table)
    return table


def basis_gradients(table: GeometryTable) -> np.ndarray:
    """``(num_cells_owned, tdim+1, gdim)``: the gradients of each owned cell's P1 basis
    functions (barycentric coordinates), in the order of the cell's vertices and P1 dofs."""
    inv = np.asarray(table.inv_map[: table.num_cells_owned])  # grad lambda_1 .. lambda_d
    return np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)


def _build_table(mesh: Any) -> GeometryTable:
    tdim = mesh.topology.dim
    gdim = mesh.geometry.dim
    if tdim != gdim:
        raise MeshError(f"only meshes with tdim == gdim are supported (got {tdim}/{gdim})")
    cmap = mesh.topology.index_map(tdim)
    n_owned = cmap.size_local
    n_cells = n_owned + cmap.num_ghosts
    verts = compat.geometry_dofmap(mesh)[:n_cells]
    if verts.shape[1] != tdim + 1:
        raise MeshError("only affine (P1 geometry) simplex meshes are supported")
    x = np.asarray(mesh.geometry.x)[:, :gdim]
    coords = x[verts]  # (n, tdim+1, gdim)
    origin = coords[:, 0, :].copy()
    jac = np.transpose(coords[:, 1:, :] - origin[:, None, :], (0, 2, 1))  # (n, gdim, tdim)
    det = np.linalg.det(jac) if n_cells else np.zeros(0)
    inv = np.linalg.inv(jac) if n_cells else np.zeros((0, tdim, gdim))
    fact = {1: 1.0, 2: 0.5, 3: 1.0 / 6.0}[tdim]
    volume = np.abs(det) * fact
    edges = []
    for i in range(tdim + 1):
        for j in range(i + 1, tdim + 1):
            edges.append(np.linalg.norm(coords[:, i] - coords[:, j], axis=1))
    h = np.max(np.stack(edges, axis=1), axis=1) if n_cells else np.zeros(0)
    h_edge = np.min(np.stack(edges, axis=1), axis=1) if n_cells else np.zeros(0)

    # Facet neighbours: triangle/tet local facet i is opposite local vertex i (basix numbering).
    c2f, c2f_off = compat.connectivity(mesh, tdim, tdim - 1)
    f2c, f2c_off = compat.connectivity(mesh, tdim - 1, tdim)
    cell_facets = c2f.reshape(-1, tdim + 1)[:n_cells]
    if tdim == 1:  # an interval's facet i is its vertex i, not the one opposite
        cell_facets = cell_facets[:, ::-1]
    counts = np.diff(f2c_off)
    first = f2c[f2c_off[:-1]]
    second = np.where(counts > 1, f2c[np.minimum(f2c_off[:-1] + 1, len(f2c) - 1)], -1)
    cells = np.arange(n_cells, dtype=np.int32)[:, None]
    a = first[cell_facets]
    b = second[cell_facets]
    neighbours = np.where(a == cells, b, a).astype(np.int32)
    exterior = np.zeros(len(counts), dtype=bool)
    ext = _exterior_facets(mesh)
    exterior[ext] = True
    on_bnd = exterior[cell_facets]
    neighbours[(neighbours < 0) & on_bnd] = -1
    neighbours[(neighbours < 0) & ~on_bnd] = -2

    lo = x.min(axis=0) if len(x) else np.full(gdim, np.inf)
    hi = x.max(axis=0) if len(x) else np.full(gdim, -np.inf)
    comm = mesh.comm
    bbox = np.empty((2, gdim))
    comm.Allreduce(np.ascontiguousarray(lo, dtype=float), bbox[0], op=MPI.MIN)
    comm.Allreduce(np.ascontiguousarray(hi, dtype=float), bbox[1], op=MPI.MAX)
    return GeometryTable(
        tdim=tdim,
        gdim=gdim,
        num_cells_owned=n_owned,
        num_cells=n_cells,
        vertices=np.ascontiguousarray(verts),
        coords=np.ascontiguousarray(coords),
        origin=np.ascontiguousarray(origin),
        inv_map=np.ascontiguousarray(inv),
        neighbours=np.ascontiguousarray(neighbours),
        facet_on_boundary=np.ascontiguousarray(on_bnd),
        volume=volume,
        h=h,
        bbox=bbox,
        node_coords=np.ascontiguousarray(x),
        h_edge=h_edge,
    )


def _exterior_facets(mesh: Any) -> np.ndarray:
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    import dolfinx.mesh  # noqa: PLC0415

    return np.asarray(dolfinx.mesh.exterior_facet_indices(mesh.topology), dtype=np.int32)


@dataclass
class Domain:
    """A mesh plus what pfem2x knows about it.

    Attributes
    ----------
    mesh:
        The DOLFINx mesh.
    kind:
        ``interval``, ``rectangle``, ``box`` or ``gmsh``.
    bounds:
        ``(2, gdim)`` array, the global bounding box.
    periodic:
        One bool per axis: opposite box faces are identified.
    cell_tags, facet_tags:
        Mesh tags from gmsh physical groups (``None`` for structured meshes).
    """

    mesh: Any
    kind: str
    bounds: np.ndarray
    periodic: tuple[bool, ...]
    cell_tags: Any = None
    facet_tags: Any = None

    @property
    def gdim(self) -> int:
        """Geometric dimension."""
        return int(self.mesh.geometry.dim)

    @property
    def comm(self) -> MPI.Comm:
        """The mesh communicator."""
        return self.mesh.comm

    @property
    def table(self) -> GeometryTable:
        """The cached geometry table."""
        return geometry_table(self.mesh)

    def num_cells_global(self) -> int:
        """Number of cells over all ranks."""
        im = self.mesh.topology.index_map(self.mesh.topology.dim)
        return int(im.size_global)

    def min_h(self) -> float:
        """Mesh size H for Courant numbers: the shortest cell edge over all ranks."""
        h = self.table.h_edge
        return float(self.comm.allreduce(h.min() if len(h) else np.inf, op=MPI.MIN))


def build_mesh(
    comm: MPI.Comm,
    kind: str,
    bounds: Any = None,
    cells: Any = None,
    diagonal: str = "right",
    file: str | os.PathLike | None = None,
    periodic: Any = None,
    partition: Any = None,
) -> Domain:
    """Build a :class:`Domain` from a mesh description.

    Parameters
    ----------
    comm:
        MPI communicator; the mesh is distributed over it.
    kind:
        ``interval`` | ``rectangle`` | ``box`` | ``gmsh``.
    bounds:
        ``[lo, hi]`` corners (scalars for an interval).
    cells:
        Cells per direction.
    diagonal:
        Triangle split of a rectangle: ``right``, ``left``, ``crossed``,
        ``left/right`` or ``right/left``.
    file:
        A gmsh ``.geo`` or ``.msh`` file for ``kind = "gmsh"``.
    periodic:
        One bool per axis.
    partition:
        ``[px, py]`` (rectangle only, ``px * py`` = ranks): split the cells
        among the ranks as a ``px x py`` grid of sub-rectangles;
        ``"columns"`` = ``[ranks, 1]``. Default (``None`` or ``"rows"``): the
        built-in meshes in strips of rows (blocks of the input numbering),
        gmsh meshes by DOLFINx's graph partitioner.

    Returns
    -------
    Domain
    """
    cell_tags = facet_tags = None
    if partition == "rows":
        partition = None
    elif partition == "columns":
        if kind != "rectangle":
            raise MeshError('mesh.partition: "columns" is only available for rectangles')
        partition = [comm.size, 1]
    if partition is not None:
        if kind != "rectangle":
            raise MeshError("mesh.partition: a [px, py] grid is only available for rectangles")
        if int(partition[0]) * int(partition[1]) != comm.size:
            raise MeshError(
                f"mesh.partition: {list(partition)} needs {int(partition[0]) * int(partition[1])}"
                f" MPI ranks, this run has {comm.size}"
            )
    if kind == "interval":
        lo, hi = float(np.ravel(bounds[0])[0]), float(np.ravel(bounds[1])[0])
        n = int(np.ravel(cells)[0])
        mesh = compat.create_interval(comm, (lo, hi), n, block_partitioner())
    elif kind == "rectangle":
        diag = diagonal.replace("/", "_")
        part = rectangle_partitioner(int(cells[0]), int(cells[1]), diag, partition)
        mesh = compat.create_rectangle(comm, bounds, cells, diag, part)
    elif kind == "box":
        mesh = compat.create_box(comm, bounds, cells, block_partitioner())
    elif kind == "gmsh":
        if file is None:
            raise MeshError("mesh.file: required for kind = 'gmsh'")
        mesh, cell_tags, facet_tags = read_geo(comm, file)
    else:
        raise MeshError(f"mesh.kind: unknown kind {kind!r}")
    compat.stable_form_keys(mesh)
    gdim = mesh.geometry.dim
    table = geometry_table(mesh)
    per = tuple(bool(p) for p in (periodic or [False] * gdim))
    if len(per) != gdim:
        raise MeshError(f"mesh.periodic: needs {gdim} entries, got {len(per)}")
    return Domain(mesh, kind, table.bbox.copy(), per, cell_tags, facet_tags)


def read_geo(comm: MPI.Comm, path: str | os.PathLike) -> tuple[Any, Any, Any]:
    """Mesh a gmsh ``.geo`` (or read a ``.msh``) file on rank 0 and distribute it.

    The highest-dimensional physical group(s) define the cells; without any
    physical group every entity of the highest dimension is used.

    Raises
    ------
    MeshError
        When the file is missing, unreadable or yields no simplex cells.
    """
    path = Path(path)
    ok = True
    msg = ""
    gdim = 0
    if comm.rank == 0:
        if not path.is_file() or not os.access(path, os.R_OK):
            ok, msg = False, f"{path}: mesh file not found or not readable"
    ok = comm.bcast(ok, root=0)
    if not ok:
        raise MeshError(comm.bcast(msg, root=0))
    import gmsh  # noqa: PLC0415

    started = getattr(gmsh, "isInitialized", lambda: False)()  # gmsh 4.8 lacks it
    if not started:
        gmsh.initialize()
    gmsh.option.setNumber("General.Terminal", 0)
    gmsh.option.setNumber("General.Verbosity", 0)
    try:
        if comm.rank == 0:
            try:
                gmsh.clear()
                gmsh.open(str(path))
                dim = gmsh.model.getDimension()
                if dim < 1:
                    raise MeshError(f"{path}: no geometry or mesh in file")
                if path.suffix != ".msh":
                    gmsh.model.mesh.generate(dim)
                if not gmsh.model.getPhysicalGroups(dim):
                    tags = [t for _, t in gmsh.model.getEntities(dim)]
                    gmsh.model.addPhysicalGroup(dim, tags, 1)
                _, elem_tags, _ = gmsh.model.mesh.getElements(dim)
                if not elem_tags or sum(len(t) for t in elem_tags) == 0:
                    raise MeshError(f"{path}: gmsh produced no cells")
                gdim = dim
            except MeshError as exc:
                ok, msg = False, str(exc)
            except Exception as exc:  # gmsh raises plain Exception on bad input
                ok, msg = False, f"{path}: gmsh could not read the file ({str(exc).strip()[:120]})"
        ok = comm.bcast(ok, root=0)
        if not ok:
            raise MeshError(comm.bcast(msg, root=0))
        gdim = comm.bcast(gdim, root=0)
        return compat.gmsh_model_to_mesh(gmsh.model, comm, 0, gdim)
    finally:
        if not started:
            gmsh.finalize()
