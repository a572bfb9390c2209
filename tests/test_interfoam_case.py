"""The Rayleigh–Taylor interFoam case generator (``benchmarks/interfoam_case.py``), no OpenFOAM."""

import re

import pytest


@pytest.fixture
def gen(benchmark_script):
    return benchmark_script("interfoam_case")


def _patch(text: str, name: str) -> str:
    return re.search(rf"{name}\s*\{{\s*type (\w+);", text).group(1)


@pytest.mark.parametrize(("sides", "side_type", "u_side"), [
    ("slip", "wall", "slip"),
    ("symmetry", "symmetryPlane", "symmetryPlane"),
    ("cyclic", "cyclic", "cyclic"),
])  # fmt: skip
def test_sides_of_the_case(gen, tmp_path, sides, side_type, u_side):
    """``--sides``: slip walls (the reference runs), symmetry planes left and right, or the
    two sides one cyclic pair (each naming the other)."""
    case = tmp_path / "case"
    assert gen.main(["make", str(case), "--nx", "4", "--ny", "8", "--dt", "0.01",
                     "--tau-end", "0.1", "--sides", sides]) is None  # fmt: skip
    mesh = (case / "system/blockMeshDict").read_text()
    assert _patch(mesh, "left") == _patch(mesh, "right") == side_type
    assert _patch(mesh, "bottom") == _patch(mesh, "top") == "wall"
    u = (case / "0/U").read_text()
    assert _patch(u, "left") == _patch(u, "right") == u_side
    assert _patch(u, "bottom") == "slip"
    for field, wall in (("0/p_rgh", "fixedFluxPressure"), ("0/alpha.heavy", "zeroGradient")):
        text = (case / field).read_text()
        side = wall if sides == "slip" else u_side
        assert _patch(text, "left") == _patch(text, "right") == side, field
    if sides == "cyclic":
        assert re.search(r"left\s*\{ type cyclic; neighbourPatch right;", mesh)
        assert re.search(r"right\s*\{ type cyclic; neighbourPatch left;", mesh)
    assert f"'sides': '{sides}'" in (case / "case.txt").read_text()


@pytest.mark.parametrize(("choice", "solver"), [("pcg", "PCG"), ("gamg", "GAMG")])
def test_pressure_solver_of_the_case(gen, tmp_path, choice, solver):
    """``--pressure-solver``: PCG/DIC (the tutorial's, the default) or GAMG, same tolerances."""
    case = tmp_path / "case"
    args = ["make", str(case), "--nx", "4", "--ny", "8", "--dt", "0.01", "--tau-end", "0.1"]
    gen.main(args + ([] if choice == "pcg" else ["--pressure-solver", choice]))
    text = (case / "system/fvSolution").read_text()
    p_rgh = re.search(r"\n\s*p_rgh \{([^}]*)\}", text).group(1)
    pcorr = re.search(r'"pcorr\.\*" \{([^}]*)\}', text).group(1)
    for entry in (p_rgh, pcorr):
        assert re.search(rf"solver {solver};", entry), entry
    assert "tolerance 1e-7; relTol 0.05;" in p_rgh
    assert f"'pressure_solver': '{choice}'" in (case / "case.txt").read_text()
