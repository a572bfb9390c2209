"""The only module that knows DOLFINx versions.

pfem2x runs on Debian bookworm's DOLFINx 0.5.2 (system Python 3.11) and on
DOLFINx 0.11 from the PyPI wheel ``dolfinx-solver-real`` (Python 3.12).
Every API difference between them is handled here; the rest of the package
imports DOLFINx names through these functions only.
"""

from __future__ import annotations

import importlib.util
from collections.abc import Callable
from typing import Any

# The PyPI wheel must be bootstrapped before dolfinx is imported.
if importlib.util.find_spec("dolfinx_solver") is not None:  # pragma: no cover - 0.11 only
    import dolfinx_solver  # noqa: F401

import contextlib
import importlib.metadata
import logging
import sys
import types
from collections.abc import Iterator

import numpy as np
from mpi4py import MPI
from petsc4py import PETSc


@contextlib.contextmanager
def _versions_without_pkg_resources() -> Iterator[None]:
    """Let UFL and FFCx read their versions without importing ``pkg_resources``.

    DOLFINx 0.5.2's UFL and FFCx take their ``__version__`` from
    ``pkg_resources.get_distribution``, and importing ``pkg_resources`` scans every
    installed distribution (60-90 ms of each process's start). While this context is
    open, ``import pkg_resources`` gives a stand-in whose ``get_distribution(name)``
    reads the version from ``importlib.metadata`` (the same metadata) and defers to the
    real module for anything it cannot answer; afterwards the stand-in is gone, so a
    later ``import pkg_resources`` imports the real one. Nothing changes where
    ``pkg_resources`` is imported already, or for packages that do not use it (DOLFINx
    0.11's).
    """
    if "pkg_resources" in sys.modules:
        yield
        return
    stand_in = types.ModuleType("pkg_resources")

    def get_distribution(name: str) -> Any:
        try:
            return types.SimpleNamespace(version=importlib.metadata.version(name))
        except Exception:  # the real module's answer (or its error)
            sys.modules.pop("pkg_resources", None)
            import pkg_resources  # noqa: PLC0415

            return pkg_resources.get_distribution(name)

    stand_in.get_distribution = get_distribution  # type: ignore[attr-defined]
    sys.modules["pkg_resources"] = stand_in
    try:
        yield
    finally:
        if sys.modules.get("pkg_resources") is stand_in:
            del sys.modules["pkg_resources"]


with _versions_without_pkg_resources():
    import dolfinx
    import dolfinx.fem
    import dolfinx.fem.petsc
    import dolfinx.geometry
    import dolfinx.mesh
    import ffcx  # noqa: F401 (imported by DOLFINx: named so that both come under the stand-in)
    import ufl  # noqa: F401

__all__ = [
    "DOLFINX_VERSION",
    "MPI",
    "PETSc",
    "dolfinx",
    "assemble_matrix",
    "assemble_vector",
    "bb_tree",
    "cell_partitioner",
    "colliding_cells",
    "create_mesh",
    "create_interval",
    "create_rectangle",
    "create_box",
    "dofmap_array",
    "function_space",
    "geometry_dofmap",
    "gmsh_model_to_mesh",
    "has_hypre",
    "preconditioner",
]

DOLFINX_VERSION: tuple[int, int, int] = tuple(
    int("".join(c for c in p if c.isdigit()) or 0) for p in dolfinx.__version__.split(".")[:3]
)  # type: ignore[assignment]
NEW_API = DOLFINX_VERSION >= (0, 8, 0)

# DOLFINx 0.5.2's JIT leaves the root logger at INFO, so every form compile
# would print compiler lines; pfem2x solvers never print.
# (cffi/setuptools raise the root logger level at each compile, so quieten
# the handlers ffcx installed rather than the logger).
logging.getLogger().setLevel(logging.WARNING)
for _h in logging.getLogger().handlers:
    _h.setLevel(logging.WARNING)


def _diagonal(name: str) -> Any:
    try:
        return getattr(dolfinx.mesh.DiagonalType, name)
    except AttributeError as exc:  # pragma: no cover - validated in scene.py
        raise ValueError(f"unknown diagonal {name!r}") from exc


Destinations = Callable[
    [MPI.Comm, int, int, np.ndarray, np.ndarray, bool], tuple[np.ndarray, np.ndarray | None]
]
"""``dest(comm, nparts, n, links, offsets, ghosting) -> (data, offsets)``: a cell partition.

Gets this rank's ``n`` input cells with their dual graph (``links`` and
``offsets`` of the neighbours' global input indices); returns the
destination rank of each cell (``offsets = None``) or, with ``ghosting``,
an adjacency list whose row ``i`` lists cell ``i``'s owner first, then the
ranks holding a ghost copy of it.
"""


def cell_partitioner(dest: Destinations) -> Any:
    """A DOLFINx cell partitioner (shared-facet ghosts) that places cells by ``dest``."""

    def part(comm: MPI.Comm, nparts: int, graph: Any, ghosting: bool) -> Any:
        import dolfinx.cpp.graph as cgraph  # noqa: PLC0415

        n = int(graph.num_nodes)
        data, offs = dest(comm, nparts, n, graph.array, graph.offsets, ghosting)
        if offs is None:
            return cgraph.AdjacencyList_int32(data)
        return cgraph.AdjacencyList_int32(data, offs)

    mode = dolfinx.mesh.GhostMode.shared_facet
    if NEW_API:
        return dolfinx.mesh.create_cell_partitioner(part, mode, 2)
    return dolfinx.mesh.create_cell_partitioner(part)


def create_interval(
    comm: MPI.Comm, bounds: tuple[float, float], n: int, partitioner: Any
) -> dolfinx.mesh.Mesh:
    """Create a uniform interval mesh of ``n`` cells on ``bounds``."""
    return dolfinx.mesh.create_interval(
        comm, int(n), [float(bounds[0]), float(bounds[1])], partitioner=partitioner
    )


def create_rectangle(
    comm: MPI.Comm, bounds: Any, n: Any, diagonal: str, partitioner: Any
) -> dolfinx.mesh.Mesh:
    """Create a triangle mesh of a rectangle, ``n = [nx, ny]`` cells, split by ``diagonal``."""
    pts = [np.asarray(bounds[0], dtype=float)[:2], np.asarray(bounds[1], dtype=float)[:2]]
    return dolfinx.mesh.create_rectangle(
        comm,
        pts,
        [int(n[0]), int(n[1])],
        cell_type=dolfinx.mesh.CellType.triangle,
        diagonal=_diagonal(diagonal),
        partitioner=partitioner,
    )


def create_box(comm: MPI.Comm, bounds: Any, n: Any, partitioner: Any) -> dolfinx.mesh.Mesh:
    """Create a tetrahedral mesh of a box, ``n = [nx, ny, nz]`` cells."""
    pts = [np.asarray(bounds[0], dtype=float)[:3], np.asarray(bounds[1], dtype=float)[:3]]
    return dolfinx.mesh.create_box(
        comm,
        pts,
        [int(n[0]), int(n[1]), int(n[2])],
        cell_type=dolfinx.mesh.CellType.tetrahedron,
        partitioner=partitioner,
    )


def create_mesh(comm: MPI.Comm, cells: np.ndarray, x: np.ndarray, gdim: int) -> dolfinx.mesh.Mesh:
    """Create an affine simplex mesh from rank-0 cell/vertex arrays (other ranks pass empties)."""
    import basix.ufl  # noqa: PLC0415

    tdim = cells.shape[1] - 1
    cell = {1: "interval", 2: "triangle", 3: "tetrahedron"}[tdim]
    if NEW_API:
        domain = basix.ufl.element("Lagrange", cell, 1, shape=(gdim,))
        return dolfinx.mesh.create_mesh(comm, cells, domain, x[:, :gdim])
    import ufl  # noqa: PLC0415

    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.Cell(cell, geometric_dimension=gdim), 1))
    return dolfinx.mesh.create_mesh(comm, cells, x[:, :gdim], domain)


def gmsh_model_to_mesh(model: Any, comm: MPI.Comm, rank: int, gdim: int) -> tuple[Any, Any, Any]:
    """Turn a gmsh model (built on ``rank``) into ``(mesh, cell_tags, facet_tags)``."""
    if NEW_API:
        import dolfinx.io.gmsh as gmshio  # noqa: PLC0415

        data = gmshio.model_to_mesh(model, comm, rank, gdim=gdim)
        return data.mesh, data.cell_tags, data.facet_tags
    from dolfinx.io import gmshio  # noqa: PLC0415

    return gmshio.model_to_mesh(model, comm, rank, gdim=gdim)


def function_space(
    mesh: Any, degree: int = 1, shape: tuple[int, ...] | None = None, family: str = "Lagrange"
) -> Any:
    """A Lagrange space of ``degree`` (vector valued when ``shape`` is given);
    ``family="DG"`` for the discontinuous one (e.g. cell-wise constants, degree 0)."""
    if NEW_API:
        return dolfinx.fem.functionspace(
            mesh, (family, degree, shape) if shape else (family, degree)
        )
    if shape:
        return dolfinx.fem.VectorFunctionSpace(mesh, (family, degree), dim=shape[0])
    return dolfinx.fem.FunctionSpace(mesh, (family, degree))


def _adjacency_to_array(adj: Any, width: int | None = None) -> np.ndarray:
    if isinstance(adj, np.ndarray):
        return adj
    arr = np.asarray(adj.array)
    if width is None:
        offs = np.asarray(adj.offsets)
        width = int(offs[1] - offs[0]) if len(offs) > 1 else 0
    return arr.reshape(-1, width) if width else arr.reshape(0, 0)


def dofmap_array(V: Any) -> np.ndarray:
    """Cell → dof table, shape ``(num_cells_local + ghosts, dofs_per_cell)`` (block indices)."""
    return np.ascontiguousarray(_adjacency_to_array(V.dofmap.list), dtype=np.int32)


def geometry_dofmap(mesh: Any) -> np.ndarray:
    """Cell → geometry node table, shape ``(num_cells_local + ghosts, nodes_per_cell)``."""
    dm = mesh.geometry.dofmaps[0] if hasattr(mesh.geometry, "dofmaps") else mesh.geometry.dofmap
    return np.ascontiguousarray(_adjacency_to_array(dm), dtype=np.int32)


def connectivity(mesh: Any, d0: int, d1: int) -> tuple[np.ndarray, np.ndarray]:
    """``(array, offsets)`` of the topology connectivity ``d0 → d1`` (created if needed)."""
    mesh.topology.create_connectivity(d0, d1)
    c = mesh.topology.connectivity(d0, d1)
    return np.asarray(c.array, dtype=np.int32), np.asarray(c.offsets, dtype=np.int32)


def bb_tree(mesh: Any) -> Any:
    """Bounding-box tree over the cells of ``mesh``."""
    tdim = mesh.topology.dim
    if NEW_API:
        return dolfinx.geometry.bb_tree(mesh, tdim)
    return dolfinx.geometry.BoundingBoxTree(mesh, tdim)


def colliding_cells(mesh: Any, tree: Any, points: np.ndarray) -> np.ndarray:
    """First local cell containing each point (``-1`` where none), points ``(n, 3)``."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.shape[0] == 0:
        return np.zeros(0, dtype=np.int32)
    if NEW_API:
        cand = dolfinx.geometry.compute_collisions_points(tree, pts)
    else:
        cand = dolfinx.geometry.compute_collisions(tree, pts)
    coll = dolfinx.geometry.compute_colliding_cells(mesh, cand, pts)
    offs = np.asarray(coll.offsets)
    arr = np.asarray(coll.array)
    out = np.full(pts.shape[0], -1, dtype=np.int32)
    has = offs[1:] > offs[:-1]
    out[has] = arr[offs[:-1][has]]
    return out


def assemble_matrix(a: Any, bcs: list | None = None, A: Any | None = None) -> Any:
    """Assemble a bilinear form into a (new or given) PETSc matrix, finalised."""
    bcs = bcs or []
    if A is None:
        A = dolfinx.fem.petsc.assemble_matrix(a, bcs=bcs)
    else:
        A.zeroEntries()
        dolfinx.fem.petsc.assemble_matrix(A, a, bcs=bcs)
    A.assemble()
    return A


def create_vector(L: Any) -> Any:
    """A ghosted PETSc vector compatible with the linear form ``L``."""
    if NEW_API:
        return dolfinx.fem.petsc.create_vector(L.function_spaces[0])
    return dolfinx.fem.petsc.create_vector(L)


def petsc_vec(u: Any) -> Any:
    """The PETSc vector wrapping a Function's dofs."""
    return u.x.petsc_vec if NEW_API else u.vector


def assemble_vector(L: Any, b: Any, a: Any | None = None, bcs: list | None = None) -> Any:
    """Assemble ``L`` into ``b`` (zeroed first), lift and set Dirichlet values, ghosts updated."""
    with b.localForm() as loc:
        loc.set(0.0)
    dolfinx.fem.petsc.assemble_vector(b, L)
    if a is not None and bcs:
        dolfinx.fem.petsc.apply_lifting(b, [a], bcs=[bcs])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    if bcs:
        dolfinx.fem.petsc.set_bc(b, bcs)
    return b


def has_hypre() -> bool:
    """Whether PETSc was built with hypre (Debian: yes; PyPI wheel: no)."""
    try:
        pc = PETSc.PC().create(PETSc.COMM_SELF)
        pc.setType("hypre")
        pc.destroy()
        return True
    except PETSc.Error:
        return False


def preconditioner(requested: str = "auto") -> str:
    """Resolve an algebraic multigrid choice: ``auto`` → hypre where available, else gamg."""
    if requested == "auto":
        return "hypre" if has_hypre() else "gamg"
    return requested


def stable_form_keys(mesh: Any) -> Any:
    """Give ``mesh`` the coordinate element FFCx compiles forms with; returns ``mesh``.

    When DOLFINx 0.5.2's form compiler (FFCx 0.5) compiles a form, it replaces
    the coordinate element of the form's mesh, in place, by its equispaced
    variant; when it finds the form in its cache, it does not. A form's cache
    key contains that element, so every form made after a compile in a process
    had other keys than the same forms in a process that found its first form
    cached: each new run compiled one more form (about 0.4 s) until the cache
    held both keys of every form. Replacing the element when the mesh is made,
    before anything has keyed or hashed it, gives every process the same keys;
    the compiled code is the same, because FFCx compiles with the equispaced
    element in either case. Later FFCx versions (DOLFINx 0.11) leave the mesh
    alone: nothing to do there.
    """
    if NEW_API:
        return mesh
    domain = mesh.ufl_domain()
    element = getattr(domain, "_ufl_coordinate_element", None)
    sub = getattr(element, "_sub_element", None)
    if sub is None or getattr(sub, "_variant", "") is not None:
        return mesh
    equi = ufl.FiniteElement(
        element.family(),
        element.cell(),
        element.degree(),
        element.quadrature_scheme(),
        variant="equispaced",
    )
    domain._ufl_coordinate_element = ufl.VectorElement(equi)
    return mesh


def form(expr: Any) -> Any:
    """Compile a UFL form (same call on both versions)."""
    return dolfinx.fem.form(expr)


def xdmf_file(comm: MPI.Comm, path: str, mode: str = "w") -> Any:
    """Open an XDMF file (ParaView reads it)."""
    import dolfinx.io  # noqa: PLC0415

    return dolfinx.io.XDMFFile(comm, path, mode)


# --- particles ---


def la_vector(index_map: Any, bs: int = 1) -> Any:
    """A distributed ``dolfinx.la`` vector of block size ``bs`` on ``index_map`` (with ghosts)."""
    import dolfinx.la  # noqa: PLC0415

    return dolfinx.la.vector(index_map, int(bs), dtype=np.float64)


def scatter_reverse_add(vec: Any) -> None:
    """Add ghost entries of a ``dolfinx.la`` vector (or ``Function.x``) into their owners."""
    import dolfinx.la  # noqa: PLC0415

    if NEW_API:
        vec.scatter_reverse(dolfinx.la.InsertMode.add)
    else:
        vec.scatter_reverse(dolfinx.la.ScatterMode.add)


def scatter_forward(vec: Any) -> None:
    """Copy owned entries of a ``dolfinx.la`` vector (or ``Function.x``) to their ghosts."""
    vec.scatter_forward()


def index_map_ghost_owners(index_map: Any) -> np.ndarray:
    """Owning rank of each ghost of ``index_map``, shape ``(num_ghosts,)``."""
    own = index_map.owners
    if callable(own):  # pragma: no cover - older bindings
        own = own()
    return np.asarray(own, dtype=np.int32)


def index_map_ghosts(index_map: Any) -> np.ndarray:
    """Global indices of the ghosts of ``index_map``, shape ``(num_ghosts,)``."""
    return np.asarray(index_map.ghosts, dtype=np.int64)


def index_map_local_range(index_map: Any) -> tuple[int, int]:
    """``[begin, end)`` global indices of the entries owned by this rank."""
    lr = index_map.local_range
    return int(lr[0]), int(lr[1])


def original_cell_index(mesh: Any) -> np.ndarray:
    """Input (partition-independent) index of each local cell, owned then ghosts."""
    return np.asarray(mesh.topology.original_cell_index, dtype=np.int64)


def bb_tree_cells(mesh: Any, cells: np.ndarray) -> Any:
    """Bounding-box tree over a subset of the local cells of ``mesh``."""
    tdim = mesh.topology.dim
    ents = np.ascontiguousarray(cells, dtype=np.int32)
    if NEW_API:
        return dolfinx.geometry.bb_tree(mesh, tdim, entities=ents)
    return dolfinx.geometry.BoundingBoxTree(mesh, tdim, ents)


# --- flow ---


def locate_boundary_facets(mesh: Any, marker: Any) -> np.ndarray:
    """Exterior facets whose vertices all satisfy ``marker(x)`` (``x`` of shape ``(3, n)``)."""
    fdim = mesh.topology.dim - 1
    mesh.topology.create_connectivity(fdim, mesh.topology.dim)
    return np.asarray(dolfinx.mesh.locate_entities_boundary(mesh, fdim, marker), dtype=np.int32)


def dirichlet_component(V: Any, comp: int | None, facets: np.ndarray, value: Any = 0.0) -> Any:
    """A Dirichlet condition on ``facets``: component ``comp`` of a vector space set to a
    constant, or (``comp is None``) every component set from the Function ``value`` on ``V``."""
    fdim = V.mesh.topology.dim - 1
    if comp is None:
        dofs = dolfinx.fem.locate_dofs_topological(V, fdim, facets)
        return dolfinx.fem.dirichletbc(value, dofs)
    Vc = V.sub(comp)
    dofs = dolfinx.fem.locate_dofs_topological(Vc, fdim, facets)
    return dolfinx.fem.dirichletbc(PETSc.ScalarType(value), dofs, Vc)


def set_bc(vec: Any, bcs: list) -> None:
    """Set the (owned) Dirichlet entries of a PETSc vector to their values."""
    if bcs:
        dolfinx.fem.petsc.set_bc(vec, bcs)


def lift(b: Any, a: Any, bcs: list) -> None:
    """``b -= A[:, bc] g``: the Dirichlet values' columns of the form ``a`` (ghosts summed).

    ``b``'s owned entries are kept; its ghost entries are overwritten.
    """
    with b.localForm() as loc:
        loc.array[b.getLocalSize() :] = 0.0
    dolfinx.fem.petsc.apply_lifting(b, [a], bcs=[bcs])
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)


def dirichlet_rows(vec: Any, bcs: list) -> np.ndarray:
    """The owned entries of ``vec``'s layout that ``bcs`` set (a bool mask)."""
    a, b, one = vec.duplicate(), vec.duplicate(), vec.duplicate()
    a.set(0.0)
    b.set(0.0)
    one.set(1.0)
    dolfinx.fem.petsc.set_bc(a, bcs)
    dolfinx.fem.petsc.set_bc(b, bcs, one)  # g - 1 on those rows (x0 = 1)
    mask = (a.array_r - b.array_r) == 1.0
    for v in (a, b, one):
        v.destroy()
    return mask


def constant_nullspace(A: Any) -> Any:
    """Attach the constant null space to ``A`` (pure-Neumann pressure); returns it."""
    ns = PETSc.NullSpace().create(constant=True, comm=A.getComm())
    A.setNullSpace(ns)
    return ns
