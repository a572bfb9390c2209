"""PFEM-2 flow: the explicit source integrated along each particle's path (paper eq. 2.9).

The Taylor–Green vortex (an exact decaying Navier–Stokes solution in a slip
box, scene ``taylor-green``) on 16 × 16 to t = 2. At Courant 8 (4 steps of
Δt = 0.5) a particle turns by up to a quarter of a revolution in one step:
the centripetal pressure acceleration must be integrated along the curved
path, with the pressure of the velocity the particles move with.
"""

import math

import pytest

from pfem2x.compat import MPI
from pfem2x.runner import build_domain, make_solver
from pfem2x.scene import load_scene

T_END = 2.0
CELLS = 16


def final_error(courant: float, *overrides: str, path: bool = True) -> tuple[float, object]:
    """``velocity_l2_error`` at t = 2 of the 16 × 16 vortex at this Courant number.

    ``path = False``: the source is the trapezoid of each path's two end points.
    """
    sc = load_scene("taylor-green", [f"mesh.cells=[{CELLS}, {CELLS}]", *overrides], variant=None)
    s = make_solver(sc, build_domain(sc, MPI.COMM_WORLD))
    if not path:
        s.path_source = False
    n = round(T_END / (courant / CELLS))  # max |u| = 1 at t = 0, h = 1/16
    dt = T_END / n
    for k in range(n):
        s.step(k * dt, dt)
    err = s.diagnostics(T_END)["velocity_l2_error"]
    assert math.isfinite(err)
    return err, s


LAG = ("method.frame=lagrangian", "flow.extra_pass=true")


def test_pfem2_error_does_not_grow_with_dt():
    """Courant 8 against Courant 1: at most 1.5 × the error, with the source on sub-steps.

    Courant 0.5 and both meshes: ``tests/test_taylor_green.py``.
    """
    e1, _ = final_error(1.0, *LAG)
    e8, s = final_error(8.0, *LAG)
    assert s.path_substeps > 8  # the source was integrated on sub-steps of the path
    assert e8 <= 1.5 * e1, (e1, e8)


@pytest.mark.mpi
def test_path_integral_beats_the_end_points():
    """The same run with the source from the two ends of each path only: worse by > 2×."""
    e_path, s = final_error(8.0, *LAG)
    e_ends, s_ends = final_error(8.0, *LAG, path=False)
    assert s.path_substeps > 1 and s_ends.path_substeps == 1
    assert e_path < 0.5 * e_ends, (e_path, e_ends)


@pytest.mark.mpi
def test_consistent_pressure_beats_the_lagged_one():
    """The source's pressure solved from u^n, against the last step's p^n: better by > 2×."""
    e_c, _ = final_error(8.0, *LAG)
    e_l, s_l = final_error(8.0, *LAG, "flow.explicit_pressure=lagged")
    assert not s_l.consistent_pressure
    assert e_c < 0.5 * e_l, (e_c, e_l)


def test_substeps_follow_the_substep_limits():
    """The source's sub-steps are the move's: many under the default limits, 1 when they allow.

    One step at Courant 8 (8 grid spacings per step at the nodal speed ~1):
    ``method.substep_courant = 10`` without the turning limit lets every
    particle cross its path in one sub-step (one pass: the second pass moves in
    ``flow.pass_splits`` parts).
    """
    dt = 8.0 / CELLS
    m = []
    for lim in ([], ["method.substep_courant=10", "method.substep_gradient=0"]):
        sc = load_scene(
            "taylor-green",
            [f"mesh.cells=[{CELLS}, {CELLS}]", *lim, *LAG[:1], "flow.extra_pass=false"],
            variant=None,
        )
        s = make_solver(sc, build_domain(sc, MPI.COMM_WORLD))
        s.step(0.0, dt)
        m.append(s.path_substeps)
    assert m[0] > 2
    assert m[1] == 1
