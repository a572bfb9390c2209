"""Dam break at density ratio 1000 (scene ``dam-break``), issue 5.

Water column a x 2a (a = 0.05715 m, Martin & Moyce's n^2 = 2 column) in air,
small variant: 40x20 cells (H = a/8), to T = t sqrt(2 g/a) = 2.0.
Reference points: :data:`pfem2x.cases.MARTIN_MOYCE_FRONT` / ``_HEIGHT``
(Martin & Moyce 1952, Tables 2 and 6, digitised as cited there).
Serial and ``mpirun -n 2`` (tests marked ``mpi``).
"""

import numpy as np
import pytest

from pfem2x.cases import MARTIN_MOYCE_FRONT, MARTIN_MOYCE_HEIGHT
from pfem2x.runner import Simulation
from pfem2x.scene import load_scene


def run(tmp, *overrides: str):
    sc = load_scene("dam-break", list(overrides), variant="small")
    sim = Simulation(sc, tmp / "out", quiet=True)
    return sim.run()


def monotone(values: np.ndarray, sign: float, tol: float) -> bool:
    """Whether ``sign * values`` never decreases by more than ``tol``."""
    return bool(np.all(np.diff(sign * values) > -tol))


@pytest.mark.mpi
def test_small_dam_break_lagrangian(shared_tmp):
    """PFEM-2 at Courant >= 2 (9 steps of T = 0.22): stable, volume, front and height vs M&M.

    Bands at T = 2 (tau = 1.41): the front Z within 0.25 of Martin & Moyce's
    curve (2 cells of a/8: the P1 phase = 1/2 iso-line of a cell-averaged
    projection sits up to a cell off the particles' front, and one step
    is dt = 0.22 in T), the height H within 0.08 (1.3 cells of a/8 in
    units of 2a). This run: Z = 2.15 (M&M 2.35), H = 0.66 (M&M 0.68).
    Water volume (cell fractions of water particles): within 12 % (9.7 %
    here; 14 % at T = 3.33 on 100x50 at Courant 2: a known deficiency, the
    water particles crowd in the thin spreading layer, see docs/RESULTS.md).
    """
    res = run(shared_tmp)
    assert res.status == "ok" and res.exit_code == 0
    s = res.summary
    assert s["frame"] == "lagrangian" and s["courant_max"] >= 2.0
    m = s["metrics"]
    assert m["volume_change_max_water"] < 0.12
    front = np.array(m["front"])
    height = np.array(m["height"])
    # Martin & Moyce's units: T = t sqrt(2 g / a), tau = t sqrt(g / a)
    assert front[-1, 0] == pytest.approx(0.108 * np.sqrt(2 * 9.81 / 0.05715), rel=1e-9)
    assert height[-1, 0] == pytest.approx(0.108 * np.sqrt(9.81 / 0.05715), rel=1e-9)
    for key in ("front", "front_particles"):
        z = np.array(m[key])[:, 1]
        assert monotone(z, 1.0, 0.02), f"{key} goes back: {z}"
    for key in ("height", "height_particles"):
        h = np.array(m[key])[:, 1]
        assert monotone(h, -1.0, 0.02), f"{key} rises: {h}"
    T, Z = front[-1]
    tau, H = height[-1]
    z_mm = np.interp(T, *MARTIN_MOYCE_FRONT.T)
    h_mm = np.interp(tau, *MARTIN_MOYCE_HEIGHT.T)
    assert abs(Z - z_mm) < 0.25, (T, Z, z_mm)
    assert abs(H - h_mm) < 0.08, (tau, H, h_mm)
    assert abs(m["front_particles"][-1][1] - z_mm) < 0.25
    assert np.all(np.isfinite(front)) and np.all(np.isfinite(height))


@pytest.mark.mpi
def test_eulerian_dam_break_exit3_above_its_limit(shared_tmp):
    """The level-set frame at Courant 2 diverges: status ``diverged``, exit 3, a message.

    (It runs at Courant <= 1: Z = 2.40 at T = 2 with Courant 1.)
    """
    res = run(shared_tmp, "method.frame=eulerian")
    assert res.status == "diverged" and res.exit_code == 3
    assert "diverged in step" in res.summary["message"]
    assert "speed" in res.summary["message"] or "finite" in res.summary["message"]


def test_eulerian_dam_break_courant1(shared_tmp):
    """Level-set frame at Courant 1 (adaptive, 20 steps): stable, front and height in the bands."""
    res = run(shared_tmp, "method.frame=eulerian", "time.courant=1", "time.adaptive=true")
    assert res.status == "ok"
    m = res.summary["metrics"]
    T, Z = m["front"][-1]
    tau, H = m["height"][-1]
    assert abs(Z - np.interp(T, *MARTIN_MOYCE_FRONT.T)) < 0.25
    assert abs(H - np.interp(tau, *MARTIN_MOYCE_HEIGHT.T)) < 0.08
    assert m["volume_change_max_water"] < 0.06
