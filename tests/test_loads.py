"""The PFEM-2 frame's cell-wise right-hand sides equal DOLFINx's assembly of their forms.

The source load and the consistent pressure's right-hand side (:mod:`pfem2x.physics.flow.loads`)
with a DG0 density in [1, 1000], the balanced force's P1 ``q`` and ``Pi``, with gravity
only and without either, on triangles and tetrahedra, serially and on 2 ranks (the ghost
rows added to their owners).
"""

from types import SimpleNamespace

import numpy as np
import pytest
import ufl

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.mesh import build_mesh, geometry_table
from pfem2x.physics.flow.loads import CellLoads


def _mesh(gdim: int):
    if gdim == 2:
        d = build_mesh(
            MPI.COMM_WORLD, "rectangle", [[-0.5, -1.0], [0.5, 1.0]], [7, 9], "left/right"
        )
    else:
        d = build_mesh(MPI.COMM_WORLD, "box", [[0, 0, 0], [1, 1, 2]], [3, 2, 4])
    return d.mesh


def _p1(space, fn):
    """A P1 function from its nodes' coordinates (the same on any partition)."""
    f = compat.dolfinx.fem.Function(space)
    bs = space.dofmap.index_map_bs
    x = space.tabulate_dof_coordinates()
    f.x.array[:] = np.column_stack([fn(x, k) for k in range(bs)]).reshape(-1)
    return f


@pytest.mark.mpi
@pytest.mark.parametrize("gdim", [2, 3])
@pytest.mark.parametrize("kind", ["jump", "gravity", "none"])
def test_cell_loads_equal_the_forms(gdim, kind):
    mesh = _mesh(gdim)
    Q = compat.function_space(mesh, 1)
    V = compat.function_space(mesh, 1, shape=(gdim,))
    W0 = compat.function_space(mesh, 0, family="DG")
    t = geometry_table(mesh)
    rho = compat.dolfinx.fem.Function(W0)
    cells = compat.dofmap_array(W0)[:, 0]
    mid = t.coords.mean(axis=1)
    rho.x.array[cells] = 1.0 + 999.0 * np.sin(7.0 * mid[:, 0] + 3.0 * mid[:, 1]) ** 2
    owned = cells[: t.num_cells_owned]
    p = _p1(Q, lambda x, k: np.cos(3.0 * x[:, 0]) * x[:, 1] + x[:, gdim - 1] ** 2)
    u = _p1(V, lambda x, k: np.sin(2.0 * x[:, 0] + k) * np.cos(x[:, 1] - 0.5 * k))
    g_np = np.zeros(gdim) if kind == "none" else np.r_[np.zeros(gdim - 1), -9.81]
    g = compat.dolfinx.fem.Constant(mesh, g_np)
    jump = None
    if kind == "jump":
        jump = SimpleNamespace(
            q=_p1(Q, lambda x, k: np.tanh(4.0 * x[:, 1]) - 0.3 * x[:, 0]),
            Pi=_p1(Q, lambda x, k: 500.0 * np.abs(x[:, 1] - 0.1) + x[:, 0]),
        )
        f_body = rho * (g - ufl.grad(jump.q)) + ufl.grad(jump.Pi)
    else:
        f_body = rho * g
    w, r = ufl.TestFunction(V), ufl.TestFunction(Q)
    gu = ufl.grad(u)
    forms = {
        "force": compat.form(ufl.dot(f_body - ufl.grad(p), w) * ufl.dx),
        "pressure": compat.form(
            ufl.inner(gu, ufl.transpose(gu)) * r * ufl.dx
            + (1.0 / rho) * ufl.dot(f_body, ufl.grad(r)) * ufl.dx
        ),
    }
    loads = CellLoads(V, Q, g_np, jump)
    errors = []
    for name, form in forms.items():
        ref = compat.create_vector(form)
        compat.assemble_vector(form, ref)
        b = ref.duplicate()
        b.set(np.nan)  # every entry is written
        if name == "force":
            loads.force(rho.x.array[owned], p, b)
        else:
            loads.pressure(rho.x.array[owned], u, b)
        b.axpy(-1.0, ref)
        errors.append(b.norm() / ref.norm())
    assert max(errors) < 1e-13, errors
