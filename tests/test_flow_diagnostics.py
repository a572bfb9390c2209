"""The flow diagnostics' per-cell velocity measures (one compiled pass over the cells)."""

import numpy as np
import pytest

from pfem2x.physics.flow._kernels import cell_velocity_kernel


@pytest.mark.parametrize(("gdim", "nv"), [(2, 3), (3, 4)])
def test_cell_velocity_measures_are_the_numpy_expressions(gdim, nv):
    rng = np.random.default_rng(gdim)
    u = rng.standard_normal((500, gdim))
    dofs = rng.integers(0, 500, (2000, nv)).astype(np.int32)
    grad = rng.standard_normal((2000, nv, gdim))
    div, speed, sq, tot = cell_velocity_kernel(u, dofs, grad)
    uc = u[dofs]
    assert np.array_equal(speed, np.linalg.norm(uc, axis=2).max(axis=1))
    assert np.array_equal(tot, np.sum(uc.sum(axis=1) ** 2, axis=1))
    # the order of numpy's own sums over the cell's (vertex, component) pairs depends on
    # its SIMD code; the kernel takes the one of triangles on x86-64
    assert np.allclose(sq, np.sum(uc**2, axis=(1, 2)), rtol=1e-14, atol=0)
    assert np.allclose(div, np.einsum("ckj,ckj->c", uc, grad), rtol=1e-12, atol=1e-13)


def test_a_nan_velocity_shows_in_its_cells():
    u = np.ones((4, 2))
    u[3, 1] = np.nan
    dofs = np.array([[0, 1, 2], [3, 0, 1], [0, 3, 1]], dtype=np.int32)
    div, speed, sq, tot = cell_velocity_kernel(u, dofs, np.ones((3, 3, 2)))
    assert speed[0] == pytest.approx(np.sqrt(2.0)) and np.isfinite(div[0])
    for c in (1, 2):  # first and middle vertex
        assert np.isnan(speed[c]) and np.isnan(div[c]) and np.isnan(sq[c]) and np.isnan(tot[c])
