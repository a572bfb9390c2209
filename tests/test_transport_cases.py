"""Case diagnostics of the paper's scalar scenes, checked against closed forms."""

import math

import numpy as np
import pytest

from pfem2x.cases import subcell_points
from pfem2x.compat import MPI
from pfem2x.runner import build_domain, make_solver
from pfem2x.scene import load_scene


def solver_for(name, *over):
    s = load_scene(name, list(over), variant="small")
    return make_solver(s, build_domain(s, MPI.COMM_WORLD))


def test_subcell_rule_integrates_linear_functions_exactly():
    for tdim, k in ((1, 5), (2, 4)):
        lam = subcell_points(tdim, k)
        assert lam.shape == (k**tdim, tdim + 1)
        assert np.allclose(lam.sum(axis=1), 1.0) and (lam > 0).all()
        # equal weights: the mean barycentric coordinate is the centroid
        assert np.allclose(lam.mean(axis=0), 1.0 / (tdim + 1))


@pytest.mark.mpi
def test_zalesak_exact_area_matches_the_slotted_disk():
    solver = solver_for("zalesak", "method.frame=characteristic")
    d = solver.diagnostics(0.0)
    # pi R^2 minus the slot |x - 50| <= 2.5 from the disk bottom up to y = 85
    r, w = 15.0, 2.5
    chord = w * math.sqrt(r * r - w * w) + r * r * math.asin(w / r)  # int_{-w}^{w} sqrt(r^2-x^2)
    area = math.pi * r * r - (2 * w * 10.0 + chord)
    assert d["area_exact"] == pytest.approx(area, rel=0.01)
    # the exact shape rotates rigidly: same area a quarter period later
    assert solver.diagnostics(157.0)["area_exact"] == pytest.approx(area, rel=0.01)
    # at t = 0 the field is the interpolated shape: symmetric difference is sub-cell only
    assert d["sym_diff"] < 0.2 * area


@pytest.mark.mpi
def test_gaussian_hill_reference_peak_follows_heat_equation():
    solver = solver_for("gaussian-hill")
    case = solver.case
    assert case.reference_peak(0.0) == pytest.approx(1.0)
    # top of the hill: lap T0 = -pi^2/sigma^2, so peak(t) = 1 - kappa t pi^2/sigma^2 + O(t^2)
    kappa, sigma = 1e-4, 0.2
    for t in (0.5, 1.0):
        lin = 1.0 - kappa * t * math.pi**2 / sigma**2
        assert case.reference_peak(t) == pytest.approx(lin, abs=2e-3)
    # and it decays monotonically
    peaks = [case.reference_peak(t) for t in (1.0, 3.0, 7.0)]
    assert peaks[0] > peaks[1] > peaks[2] > 0.5
    d = solver.diagnostics(0.0)
    assert d["peak"] == pytest.approx(1.0)  # x0 = (1/6, 1/6) is a mesh node of the 12x12 mesh
