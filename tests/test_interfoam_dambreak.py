"""The dam-break interFoam case generator (``benchmarks/interfoam_dambreak.py``), no OpenFOAM."""

import re

import numpy as np
import pytest

from pfem2x.cases import MARTIN_MOYCE_FRONT, MARTIN_MOYCE_HEIGHT


@pytest.fixture
def gen(benchmark_script):
    return benchmark_script("interfoam_dambreak")


def _patch(text: str, name: str) -> str:
    return re.search(rf"{name}\s*\{{\s*type (\w+);", text).group(1)


@pytest.mark.parametrize("floor", ["slip", "noslip"])
def test_case_is_the_scene_with_its_floor(gen, tmp_path, floor):
    """The box, the fluids and the column come from the scene; ``--floor`` sets the floor."""
    case = tmp_path / "case"
    assert gen.main(["make", str(case), "--nx", "10", "--ny", "5", "--floor", floor]) is None
    pb = gen.dam_break_from_scene()
    assert (pb.a, pb.n2, pb.rho_water, pb.rho_air) == (0.05715, 2.0, 1000.0, 1.0)
    u = (case / "0/U").read_text()
    assert _patch(u, "bottom") == {"slip": "slip", "noslip": "noSlip"}[floor]
    assert _patch(u, "left") == _patch(u, "right") == _patch(u, "top") == "slip"
    info = gen.interfoam_case.eval_case_txt(case)
    assert info["floor"] == floor and info["nx"] == 10
    rows = gen.case_front(case)  # t = 0 only: the initial column
    assert rows.shape == (1, 6)
    assert rows[0, 2] == pytest.approx(1.0) and rows[0, 4] == pytest.approx(1.0)


def test_initial_column_is_exact_on_any_grid(gen):
    """Cell area fractions of the column sum to its area; the front and height of the
    initial field sit on the column's edges where they are cell faces."""
    pb = gen.dam_break_from_scene()
    cell = (pb.x1 - pb.x0) * (pb.y1 - pb.y0)
    for nx, ny in ((100, 50), (37, 23)):
        a = gen.initial_alpha(pb, nx, ny)
        assert a.min() >= 0.0 and a.max() <= 1.0
        assert a.sum() * cell / (nx * ny) == pytest.approx(pb.n2 * pb.a**2, rel=1e-12)
    z, h = gen.front_height(gen.initial_alpha(pb, 100, 50), pb, 100, 50)
    assert (z, h) == (pytest.approx(1.0, abs=1e-12), pytest.approx(1.0, abs=1e-12))


def test_front_is_the_farthest_crossing_of_any_row(gen):
    """A tongue of water along the floor and a droplet further on: the droplet's far edge."""
    pb = gen.dam_break_from_scene()
    nx, ny = 100, 50
    a = np.zeros((ny, nx))
    a[:40, :20] = 1.0
    a[0, :50] = 1.0  # tongue
    a[3, 70] = 0.75  # droplet: 0.5 is reached 1/3 of a cell beyond its centre
    dx = (pb.x1 - pb.x0) / nx
    z, h = gen.front_height(a.ravel(), pb, nx, ny)
    assert z * pb.a == pytest.approx((70.5 + 1.0 / 3.0) * dx)
    assert h == pytest.approx(1.0)


def test_summary_of_a_front_ahead_by_a_constant(gen):
    """A curve 0.2 a ahead of Martin & Moyce at every time: error 0.2 and mean lead 0.2."""
    T = np.union1d(np.linspace(0.0, 3.4, 69), MARTIN_MOYCE_FRONT[:, 0])
    Z = np.interp(T, *MARTIN_MOYCE_FRONT.T) + 0.2
    tau = T / np.sqrt(2.0)
    H = np.interp(tau, *MARTIN_MOYCE_HEIGHT.T)
    vol = np.full_like(T, 2.0)
    vol[5] = 2.002
    rows = np.column_stack([T, T, Z, tau, H, vol])
    s = gen.summarise(rows)
    assert s["front_error"] == pytest.approx(0.2)
    assert s["mean_front_lead"] == pytest.approx(0.2)
    assert s["Z_last"] == pytest.approx(4.31)
    assert s["height_error"] == pytest.approx(0.0, abs=1e-12)
    assert s["volume_change_max"] == pytest.approx(1e-3)


def test_energy_lost_of_a_lowered_column(gen, tmp_path):
    """The column a x 2a lowered to 2a x a, everything moving up at v: the released
    potential energy (rho_w - rho_air) g a^3 against the kinetic energy of the box."""
    case = tmp_path / "case"
    gen.main(["make", str(case), "--nx", "100", "--ny", "50"])
    pb = gen.dam_break_from_scene()
    a = np.zeros((50, 100))
    a[:20, :40] = 1.0  # cells of a / 20
    v = 0.3
    _field(case / "0.01" / "alpha.water", a.ravel())
    (case / "0.01" / "U").write_text("internalField uniform (0 0.3 0);\n")
    released = (pb.rho_water - pb.rho_air) * pb.g * pb.a**3
    box = (pb.x1 - pb.x0) * (pb.y1 - pb.y0)
    kinetic = 0.5 * v**2 * (pb.rho_water * 2 * pb.a**2 + pb.rho_air * (box - 2 * pb.a**2))
    assert gen.energy_lost(case) == pytest.approx(1.0 - kinetic / released, rel=1e-9)
    assert gen.case_front(case)[-1, 2] == pytest.approx(2.0)  # front Z = 2


def _field(path, values):
    path.parent.mkdir(parents=True, exist_ok=True)
    body = "\n".join(f"{v:.17g}" for v in values)
    path.write_text(f"internalField nonuniform List<scalar>\n{len(values)}\n(\n{body}\n)\n;\n")


def test_packaged_reference_is_the_stored_finest_run():
    """The package's interFoam front and height (``pfem2x.cases.interfoam_dam_break``) are
    the stored 400 x 200 run's, rounded to 4-5 digits."""
    from pathlib import Path

    from pfem2x.cases import interfoam_dam_break

    ref = interfoam_dam_break()
    root = Path(__file__).resolve().parents[1]
    rows = np.loadtxt(root / "docs/data/dam-break/interfoam/r400_co0.5/front.csv",
                      delimiter=",", skiprows=1)  # fmt: skip
    assert ref.shape == (len(rows), 4)
    assert np.abs(ref - rows[:, [1, 2, 3, 4]]).max() < 1e-4


def test_front_of_a_case_that_has_not_run(gen, tmp_path, capsys):
    """``front`` before ``run``: one error line, exit 2, no ``front.csv``; ``front`` of a
    folder that is no case names it."""
    case = tmp_path / "case"
    gen.main(["make", str(case), "--nx", "10", "--ny", "5"])
    for target in (case, tmp_path):
        with pytest.raises(SystemExit) as e:
            gen.main(["front", str(target)])
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and str(target) in err[0]
    assert not (case / "front.csv").exists()
