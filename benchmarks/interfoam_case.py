"""Rayleigh-Taylor for OpenFOAM interFoam: write the case, run it, read the tips.

Usage::

    python benchmarks/interfoam_case.py make CASE --nx 100 --ny 400 (--max-co 0.5 | --dt 0.001)
        [--tau-end 2.5] [--write-every 0.025] [--sign 1] [--sides slip] [--nproc 2]
    python benchmarks/interfoam_case.py run CASE [--np 1] [--tlim 1500]
    python benchmarks/interfoam_case.py tips CASE [--quiet]

The problem is the scene ``pfem2x/scenes/rayleigh-taylor.toml``: its ``[params]`` (d, g,
densities, viscosity) and ``[mesh] bounds`` are read from the scene file, so both codes
solve the same flow. Heavy fluid (phase ``heavy``, ``alpha.heavy = 1``) above light fluid,
equal dynamic viscosity, no surface tension, slip on all four walls, fluids at rest,
interface y = sign * 0.1 d cos(2 pi x / d) (``--sign -1`` flips it: spike on the axis).
``--sides symmetry`` makes the left and right sides ``symmetryPlane`` patches (every field
mirrored) instead of walls with ``slip`` velocity, ``fixedFluxPressure`` and ``zeroGradient``
alpha; ``--sides cyclic`` joins them into one periodic pair (no side boundary at all: the
flow, symmetric about x = 0 and x = +-d/2, is the slip walls' without their discretisation).
``alpha.heavy`` at t = 0 is the area fraction of each cell above that curve (Gauss-Legendre
quadrature of the clipped column height, written as a nonuniform list: no setFields).

Numerics are those of the damBreak tutorial of OpenFOAM v1912 (``apt-get install
openfoam``): Euler in time, MULES (semi-implicit, ``MULESCorr yes``, 2 alpha correctors,
vanLeer for alpha), PIMPLE with 1 outer and 3 pressure correctors, no momentum predictor,
PCG/DIC for ``p_rgh`` (``--pressure-solver gamg``: GAMG, the same tolerances). The step is
adaptive (``--max-co``: ``maxCo = maxAlphaCo``) or fixed (``--dt``). One 2D layer of NX x NY
hexahedra; ``alpha.heavy`` is written every ``--write-every`` time units (a ``writeObjects``
function object), all fields at the end.

``run`` calls blockMesh and interFoam (``--np 2``: decomposePar into horizontal strips,
``mpirun``, reconstructPar of alpha) with logs ``log.*`` in the case and the wall time of
interFoam in ``wallclock.txt``; ``tips`` writes ``tips.csv`` (columns ``t``, ``tau``,
``y_spike``, ``y_bubble``, ``volume``): for every written ``alpha.heavy`` the lowest and the
highest point of the ``alpha = 0.5`` iso-line, found column by column by linear
interpolation between cell centres. Time: solver time t is in units sqrt(d/g);
Tryggvason's tau = t sqrt(A g / d) with the Atwood number A.
"""

from __future__ import annotations

import argparse
import gzip
import math
import os
import re
import shutil
import subprocess
import sys
import time
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "pfem2x" / "scenes" / "rayleigh-taylor.toml"
FOAM_BASHRC = Path("/usr/share/openfoam/etc/bashrc")
AMPLITUDE = 0.1  # interface amplitude in units of d (the scene's phases.heavy.region)
TIP_TAUS = (1.0, 1.5, 2.0, 2.25, 2.5)


@dataclass(frozen=True)
class Box:
    """The rectangle [x0, x1] x [y0, y1] of a scene's mesh."""

    x0: float
    x1: float
    y0: float
    y1: float


@dataclass(frozen=True)
class Problem(Box):
    """The Rayleigh-Taylor problem as the scene states it."""

    d: float
    g: float
    rho_heavy: float
    rho_light: float
    mu: float

    @property
    def atwood(self) -> float:
        """Atwood number (rho_heavy - rho_light) / (rho_heavy + rho_light)."""
        return (self.rho_heavy - self.rho_light) / (self.rho_heavy + self.rho_light)

    @property
    def time_factor(self) -> float:
        """tau / t = sqrt(A g / d)."""
        return math.sqrt(self.atwood * self.g / self.d)


def problem_from_scene(path: Path = SCENE) -> Problem:
    """Read domain, densities, viscosity and gravity from the Rayleigh-Taylor scene file."""
    s = tomllib.loads(path.read_text())
    p = s["params"]
    (x0, y0), (x1, y1) = s["mesh"]["bounds"]
    return Problem(
        x0=float(x0), x1=float(x1), y0=float(y0), y1=float(y1), d=float(p["d"]),
        g=float(p["g"]), rho_heavy=float(p["rho_heavy"]), rho_light=float(p["rho_light"]),
        mu=float(p["mu"]),
    )  # fmt: skip


@dataclass(frozen=True)
class CaseSpec:
    """What ``make`` writes (also stored in the case as ``case.txt``)."""

    nx: int
    ny: int
    max_co: float | None = None
    dt: float | None = None
    tau_end: float = 2.5
    write_every: float = 0.025
    sign: float = 1.0
    nproc: int = 2
    #: the left and right sides: "slip" walls, "symmetry" planes or "cyclic" (one periodic pair)
    sides: str = "slip"
    #: the pressure solver: "pcg" (PCG/DIC, the tutorial's) or "gamg" (GAMG, DIC smoother)
    pressure_solver: str = "pcg"


# --------------------------------------------------------------------------- writing
def _foam_file(path: Path, cls: str, obj: str, body: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    head = (
        "FoamFile\n{\n    version     2.0;\n    format      ascii;\n"
        f"    class       {cls};\n    object      {obj};\n}}\n\n"
    )
    path.write_text(head + body.strip() + "\n")


def initial_alpha(pb: Problem, nx: int, ny: int, sign: float, order: int = 16) -> np.ndarray:
    """Area fraction of every cell above y = sign * AMPLITUDE d cos(2 pi x / d).

    Returns an (ny * nx,) array in blockMesh's cell order (x fastest). Per cell the
    fraction is the mean over x of the clipped height of the column above the curve,
    integrated with ``order`` Gauss-Legendre points per cell.
    """
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    xi, wi = np.polynomial.legendre.leggauss(order)
    x = pb.x0 + dx * (np.arange(nx)[:, None] + 0.5 * (xi[None, :] + 1.0))  # (nx, order)
    eta = sign * AMPLITUDE * pb.d * np.cos(2.0 * np.pi * x / pb.d)
    ybot = pb.y0 + dy * np.arange(ny)  # (ny,)
    h = np.clip(ybot[:, None, None] + dy - eta[None, :, :], 0.0, dy) / dy  # (ny, nx, order)
    return (0.5 * h @ wi).ravel()


SIDES = ("left", "right", "bottom", "top")
#: the velocity of a wall of pfem2x's kind (``flow.walls``, ``flow.<side>``)
WALL_BC = {"noslip": "type noSlip;", "slip": "type slip;"}
#: p_rgh and alpha on every wall
P_RGH_WALL = "type fixedFluxPressure; value uniform 0;"
ALPHA_WALL = "type zeroGradient;"


def boundary_field(entries: dict[str, str]) -> str:
    """A ``boundaryField`` block: ``{patch: entry}`` for the sides, ``empty`` front and back."""
    walls = "".join(f"    {w} {{ {e} }}\n" for w, e in entries.items())
    return f"boundaryField\n{{\n{walls}    frontAndBack {{ type empty; }}\n}}\n"


#: the left and right patches' type and their fields' entry, by ``CaseSpec.sides``
SIDE_PATCHES = {"symmetry": "symmetryPlane", "cyclic": "cyclic"}


def _sides(entry: str, sides: str = "slip") -> dict[str, str]:
    side = f"type {SIDE_PATCHES[sides]};" if sides in SIDE_PATCHES else entry
    return {"left": side, "right": side, "bottom": entry, "top": entry}


def adaptive_step(dt0: float, max_co: float, max_dt: float) -> str:
    """controlDict lines of a step adapted to ``maxCo = maxAlphaCo = max_co``."""
    return (
        f"deltaT {dt0:g};\nadjustTimeStep yes;\nmaxCo {max_co:g};\n"
        f"maxAlphaCo {max_co:g};\nmaxDeltaT {max_dt:g};\n"
        "writeControl adjustableRunTime;\n"
    )


def write_objects(name: str, objects: str, control: str, every: float) -> str:
    """A ``writeObjects`` function object: ``objects`` written every ``every``."""
    return f"""    {name}
    {{
        type writeObjects;
        libs ("libutilityFunctionObjects.so");
        objects ({objects});
        writeControl {control};
        writeInterval {every:g};
    }}
"""


def write_control(
    case: Path, end: float, step: str, functions: str, time_precision: int = 8
) -> None:
    """``system/controlDict`` of interFoam to ``end``: the ``step`` lines (time step and
    ``writeControl``), fields written at the end only, the function objects
    ``functions``."""
    _foam_file(case / "system/controlDict", "dictionary", "controlDict", f"""
application interFoam;
startFrom startTime;
startTime 0;
stopAt endTime;
endTime {end:.10g};
{step}writeInterval {end:.10g};
purgeWrite 0;
writeFormat ascii;
writePrecision 8;
writeCompression on;
timeFormat general;
timePrecision {time_precision};
runTimeModifiable no;
functions
{{
{functions}}}
""")  # fmt: skip


def write_case(case: Path, spec: CaseSpec, pb: Problem | None = None) -> None:
    """Write a complete interFoam case for ``spec`` into the folder ``case``."""
    if (spec.max_co is None) == (spec.dt is None):
        raise ValueError("give exactly one of max_co and dt")
    pb = pb or problem_from_scene()
    case.mkdir(parents=True, exist_ok=True)
    nx, ny = spec.nx, spec.ny
    t_end = spec.tau_end / pb.time_factor
    # end on a write time at or after tau_end, so that the tips can be interpolated there
    end = math.ceil(t_end / spec.write_every - 1e-9) * spec.write_every
    if spec.sides not in ("slip", *SIDE_PATCHES):
        raise ValueError(f"sides: slip, symmetry or cyclic, not {spec.sides!r}")
    write_block_mesh(case, pb, nx, ny, SIDE_PATCHES.get(spec.sides, "wall"))
    if spec.max_co is not None:
        dy = (pb.y1 - pb.y0) / ny
        step = adaptive_step(0.1 * dy, spec.max_co, spec.write_every)
        control = "adjustableRunTime"
    else:
        # interFoam reads maxCo and maxAlphaCo whether the step adapts or not
        step = (
            f"deltaT {spec.dt:g};\nadjustTimeStep no;\nmaxCo 1e6;\nmaxAlphaCo 1e6;\n"
            "writeControl runTime;\n"
        )
        control = "runTime"
    write_control(
        case, end, step, write_objects("alphaHistory", "alpha.heavy", control, spec.write_every)
    )
    write_numerics(case, "heavy", spec.pressure_solver)
    _foam_file(case / "system/decomposeParDict", "dictionary", "decomposeParDict", f"""
numberOfSubdomains {spec.nproc};
method simple;
coeffs {{ n (1 {spec.nproc} 1); }}
""")  # fmt: skip
    write_fluids(case, ("heavy", pb.rho_heavy, pb.mu), ("light", pb.rho_light, pb.mu), pb.g)
    write_fields(
        case, "heavy", initial_alpha(pb, nx, ny, spec.sign),
        _sides("type slip;", spec.sides), _sides(P_RGH_WALL, spec.sides),
        _sides(ALPHA_WALL, spec.sides), digits=10,
    )  # fmt: skip
    (case / "case.txt").write_text(repr(asdict(spec) | asdict(pb)) + "\n")


def write_fluids(
    case: Path, phase1: tuple[str, float, float], phase2: tuple[str, float, float],
    g: float, sigma: float = 0.0,
) -> None:  # fmt: skip
    """``constant/``: two Newtonian phases ``(name, rho, mu)`` (phase 1 is ``alpha``'s),
    gravity ``(0, -g, 0)``, laminar, surface tension ``sigma``."""
    fluids = "".join(
        f"{n} {{ transportModel Newtonian; nu {mu / rho:.12g}; rho {rho:g}; }}\n"
        for n, rho, mu in (phase1, phase2)
    )
    _foam_file(case / "constant/transportProperties", "dictionary", "transportProperties",
               f"phases ({phase1[0]} {phase2[0]});\n{fluids}sigma {sigma:.12g};")  # fmt: skip
    _foam_file(case / "constant/g", "uniformDimensionedVectorField", "g",
               f"dimensions [0 1 -2 0 0 0 0];\nvalue (0 {-g:.12g} 0);")  # fmt: skip
    _foam_file(case / "constant/turbulenceProperties", "dictionary", "turbulenceProperties",
               "simulationType laminar;")  # fmt: skip


def write_fields(
    case: Path, phase: str, alpha: np.ndarray, u_bc: dict[str, str],
    p_bc: dict[str, str] | None = None, alpha_bc: dict[str, str] | None = None,
    digits: int = 12,
) -> None:  # fmt: skip
    """``0/``: ``U`` at rest, ``p_rgh`` zero and ``alpha.<phase>`` (one value per cell),
    each with its boundary entries ``{patch: entry}`` (default: walls)."""
    p_bc = p_bc or dict.fromkeys(SIDES, P_RGH_WALL)
    alpha_bc = alpha_bc or dict.fromkeys(SIDES, ALPHA_WALL)
    _foam_file(case / "0/U", "volVectorField", "U",
               "dimensions [0 1 -1 0 0 0 0];\ninternalField uniform (0 0 0);\n"
               + boundary_field(u_bc))  # fmt: skip
    _foam_file(case / "0/p_rgh", "volScalarField", "p_rgh",
               "dimensions [1 -1 -2 0 0 0 0];\ninternalField uniform 0;\n"
               + boundary_field(p_bc))  # fmt: skip
    values = "\n".join(f"{v:.{digits}g}" for v in alpha)
    _foam_file(case / f"0/alpha.{phase}", "volScalarField", f"alpha.{phase}",
               "dimensions [0 0 0 0 0 0 0];\n"
               f"internalField nonuniform List<scalar>\n{alpha.size}\n(\n{values}\n)\n;\n"
               + boundary_field(alpha_bc))  # fmt: skip


# --------------------------------------------------------------------------- running
def write_block_mesh(case: Path, pb: Any, nx: int, ny: int, side_type: str = "wall") -> None:
    """``system/blockMeshDict``: ``nx`` x ``ny`` hexahedra in one layer over
    ``[pb.x0, pb.x1] x [pb.y0, pb.y1]``, walls bottom/top, left/right of ``side_type``
    (``wall``, ``symmetryPlane`` or ``cyclic``: each the other's neighbour), ``empty``
    front/back."""
    pair = {"left": "", "right": ""}
    if side_type == "cyclic":
        pair = {"left": " neighbourPatch right;", "right": " neighbourPatch left;"}
    dz = (pb.x1 - pb.x0) / nx
    v = [(pb.x0, pb.y0), (pb.x1, pb.y0), (pb.x1, pb.y1), (pb.x0, pb.y1)]
    verts = " ".join(f"({x:g} {y:g} {z:g})" for z in (0.0, dz) for x, y in v)
    _foam_file(case / "system/blockMeshDict", "dictionary", "blockMeshDict", f"""
scale 1;
vertices ( {verts} );
blocks ( hex (0 1 2 3 4 5 6 7) ({nx} {ny} 1) simpleGrading (1 1 1) );
edges ();
boundary
(
    left   {{ type {side_type};{pair["left"]} faces ((0 4 7 3)); }}
    right  {{ type {side_type};{pair["right"]} faces ((1 2 6 5)); }}
    bottom {{ type wall; faces ((0 1 5 4)); }}
    top    {{ type wall; faces ((3 7 6 2)); }}
    frontAndBack {{ type empty; faces ((0 3 2 1) (4 5 6 7)); }}
);
mergePatchPairs ();
""")  # fmt: skip


def write_numerics(case: Path, alpha: str, pressure_solver: str = "pcg") -> None:
    """``system/fvSchemes`` and ``system/fvSolution``: the damBreak tutorial's numerics
    (MULES with ``cAlpha 1``, PIMPLE without momentum predictor) for ``alpha.<alpha>``.

    ``pressure_solver``: ``"pcg"`` (PCG with DIC, the tutorial's) or ``"gamg"`` (GAMG with
    the DIC smoother; the same tolerances, far fewer sweeps on fine grids).
    """
    if pressure_solver not in ("pcg", "gamg"):
        raise ValueError(f"pressure_solver: pcg or gamg, not {pressure_solver!r}")
    ps = "PCG; preconditioner DIC" if pressure_solver == "pcg" else "GAMG; smoother DIC"
    _foam_file(case / "system/fvSchemes", "dictionary", "fvSchemes", """
ddtSchemes { default Euler; }
gradSchemes { default Gauss linear; }
divSchemes
{
    div(rhoPhi,U) Gauss linearUpwind grad(U);
    div(phi,alpha) Gauss vanLeer;
    div(phirb,alpha) Gauss linear;
    div(((rho*nuEff)*dev2(T(grad(U))))) Gauss linear;
}
laplacianSchemes { default Gauss linear corrected; }
interpolationSchemes { default linear; }
snGradSchemes { default corrected; }
""")  # fmt: skip
    _foam_file(case / "system/fvSolution", "dictionary", "fvSolution", f"""
solvers
{{
    "alpha.{alpha}.*"
    {{
        nAlphaCorr 2; nAlphaSubCycles 1; cAlpha 1; MULESCorr yes; nLimiterIter 5;
        solver smoothSolver; smoother symGaussSeidel; tolerance 1e-8; relTol 0;
    }}
    "pcorr.*" {{ solver {ps}; tolerance 1e-5; relTol 0; }}
    p_rgh {{ solver {ps}; tolerance 1e-7; relTol 0.05; }}
    p_rghFinal {{ $p_rgh; relTol 0; }}
    U {{ solver smoothSolver; smoother symGaussSeidel; tolerance 1e-6; relTol 0; }}
}}
PIMPLE
{{
    momentumPredictor no;
    nOuterCorrectors 1;
    nCorrectors 3;
    nNonOrthogonalCorrectors 0;
    pRefCell 0;
    pRefValue 0;
}}
relaxationFactors {{ equations {{ ".*" 1; }} }}
""")  # fmt: skip


def _foam(cmd: str, case: Path, log: str, timeout: float | None = None) -> int:
    """Run an OpenFOAM command line in ``case`` with the v1912 environment; return its code."""
    if not FOAM_BASHRC.is_file():
        raise FileNotFoundError(f"{FOAM_BASHRC} (apt-get install openfoam)")
    script = f"source {FOAM_BASHRC} >/dev/null 2>&1; {cmd}"
    with open(case / log, "w") as f:
        try:
            return subprocess.run(
                ["bash", "-c", script], cwd=case, stdout=f, stderr=subprocess.STDOUT,
                timeout=timeout,
            ).returncode  # fmt: skip
        except subprocess.TimeoutExpired:
            f.write(f"\n[interfoam_case] stopped after {timeout:g} s\n")
            return -15


def run_case(case: Path, nproc: int = 1, tlim: float = 1500.0) -> dict[str, float | int]:
    """blockMesh + interFoam (serial, or ``nproc`` MPI ranks); return code and wall seconds."""
    if _foam("blockMesh", case, "log.blockMesh") != 0:
        raise RuntimeError(f"blockMesh failed: {case / 'log.blockMesh'}")
    if nproc > 1:
        if _foam("decomposePar -force", case, "log.decomposePar") != 0:
            raise RuntimeError(f"decomposePar failed: {case / 'log.decomposePar'}")
        root = ["--allow-run-as-root"] if os.geteuid() == 0 else []
        cmd = " ".join(["mpirun", *root, "--oversubscribe", "-np", str(nproc), "interFoam"])
        cmd += " -parallel"
    else:
        cmd = "interFoam"
    t0 = time.perf_counter()
    rc = _foam(cmd, case, "log.interFoam", timeout=tlim)
    wall = time.perf_counter() - t0
    if nproc > 1:
        _foam("reconstructPar -fields '(alpha.heavy)'", case, "log.reconstructPar")
    (case / "wallclock.txt").write_text(f"np={nproc} rc={rc} wall_s={wall:.3f}\n")
    return {"rc": rc, "wall": wall}


# --------------------------------------------------------------------------- tips
def _read_text(path: Path) -> str | None:
    if path.is_file():
        return path.read_text()
    gz = path.with_name(path.name + ".gz")
    if gz.is_file():
        with gzip.open(gz, "rt") as f:
            return f.read()
    return None


def read_internal_vector(path: Path, ncells: int) -> np.ndarray | None:
    """The internalField of an ASCII volVectorField as (ncells, 3); None if absent."""
    text = _read_text(path)
    if text is None:
        return None
    m = re.search(r"internalField\s+uniform\s+\(([^)]*)\)", text)
    if m is not None:
        return np.tile(np.array(m.group(1).split(), dtype=float), (ncells, 1))
    m = re.search(r"internalField\s+nonuniform\s+List<vector>\s*(\d+)\s*\(", text)
    if m is None:
        return None
    n = int(m.group(1))
    body = text[m.end() :].replace("(", " ").replace(")", " ")
    return np.array(body.split(None, 3 * n)[: 3 * n], dtype=float).reshape(n, 3)


def read_internal_scalar(path: Path) -> np.ndarray | None:
    """The internalField of an ASCII volScalarField (plain or ``.gz``); None if absent."""
    text = _read_text(path)
    if text is None:
        return None
    m = re.search(r"internalField\s+nonuniform\s+List<scalar>\s*(\d+)\s*\(", text)
    if m is None:
        return None
    n = int(m.group(1))
    return np.array(text[m.end() :].split(None, n)[:n], dtype=float)


def iso_extent(alpha: np.ndarray, nx: int, ny: int, y0: float, y1: float) -> tuple[float, float]:
    """Lowest and highest y of the ``alpha = 0.5`` line over all cell columns.

    ``alpha`` is in blockMesh order (x fastest). In each column the line crosses between
    two cell centres where ``alpha - 0.5`` changes sign; the crossing is interpolated
    linearly. Returns (nan, nan) if no column has a crossing.
    """
    a = alpha.reshape(ny, nx) - 0.5
    dy = (y1 - y0) / ny
    yc = y0 + (np.arange(ny) + 0.5) * dy
    lo, hi = a[:-1], a[1:]
    cross = (lo < 0.0) != (hi < 0.0)
    if not cross.any():
        return math.nan, math.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        y = yc[:-1, None] + dy * lo / (lo - hi)
    y = y[cross]
    return float(y.min()), float(y.max())


def time_dirs(case: Path) -> list[tuple[float, Path]]:
    """The numbered time folders of a case, sorted by time."""
    out = []
    for d in case.iterdir():
        try:
            out.append((float(d.name), d))
        except ValueError:
            continue
    return sorted(out)


def case_tips(case: Path) -> np.ndarray:
    """Rows (t, tau, y_spike, y_bubble, volume) for every written ``alpha.heavy`` of a case."""
    info = eval_case_txt(case)
    pb = Problem(**{k: info[k] for k in Problem.__dataclass_fields__})
    nx, ny = int(info["nx"]), int(info["ny"])
    cell = (pb.x1 - pb.x0) / nx * (pb.y1 - pb.y0) / ny
    rows = []
    for t, d in time_dirs(case):
        a = read_internal_scalar(d / "alpha.heavy")
        if a is None or a.size != nx * ny:
            continue
        lo, hi = iso_extent(a, nx, ny, pb.y0, pb.y1)
        rows.append((t, t * pb.time_factor, lo, hi, float(a.sum() * cell)))
    return np.array(rows, dtype=float).reshape(-1, 5)


def eval_case_txt(case: Path) -> dict[str, float]:
    """The parameters ``make`` stored in ``case.txt`` (a dict of numbers)."""
    import ast

    return ast.literal_eval((case / "case.txt").read_text())


def write_tips(case: Path) -> np.ndarray:
    """Write ``case/tips.csv`` (t, tau, y_spike, y_bubble, volume) and return its rows."""
    rows = case_tips(case)
    np.savetxt(case / "tips.csv", rows, delimiter=",", fmt="%.8g",
               header="t,tau,y_spike,y_bubble,volume", comments="")  # fmt: skip
    return rows


def tips_at(rows: np.ndarray, taus: tuple[float, ...] = TIP_TAUS) -> dict[str, list[float]]:
    """Spike and bubble interpolated linearly in tau (nan outside the written range)."""
    tau = rows[:, 1]
    out: dict[str, list[float]] = {"spike": [], "bubble": []}
    for k, col in (("spike", 2), ("bubble", 3)):
        for t in taus:
            ok = len(tau) > 0 and tau[0] <= t <= tau[-1] + 1e-6
            out[k].append(float(np.interp(t, tau, rows[:, col])) if ok else math.nan)
    return out


# --------------------------------------------------------------------------- command line
def fail(msg: str) -> NoReturn:
    """One ``error:`` line on stderr, exit code 2."""
    print(f"error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def fresh_case(case: Path, overwrite: bool) -> None:
    """Make room for a new case in ``case``: fail if it holds files, unless ``overwrite``."""
    if case.exists() and any(case.iterdir()):
        if not overwrite:
            fail(f"{case}: exists and is not empty (use --overwrite)")
        shutil.rmtree(case)


def main(argv: list[str] | None = None) -> None:
    """Command line: ``make``, ``run`` and ``tips`` (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    mk = sub.add_parser("make", help="write a case folder")
    mk.add_argument("case", type=Path)
    mk.add_argument("--nx", type=int, required=True)
    mk.add_argument("--ny", type=int, required=True)
    step = mk.add_mutually_exclusive_group(required=True)
    step.add_argument("--max-co", type=float, help="adaptive step: maxCo = maxAlphaCo")
    step.add_argument("--dt", type=float, help="fixed step")
    mk.add_argument("--tau-end", type=float, default=2.5)
    mk.add_argument("--write-every", type=float, default=0.025, help="alpha output interval")
    mk.add_argument("--sign", type=float, default=1.0, choices=(1.0, -1.0))
    mk.add_argument("--nproc", type=int, default=2, help="ranks for decomposeParDict")
    mk.add_argument(
        "--sides", choices=("slip", "symmetry", "cyclic"), default="slip", help="left/right"
    )
    mk.add_argument(
        "--pressure-solver",
        choices=("pcg", "gamg"),
        default="pcg",
        help="p_rgh: PCG/DIC (the tutorial's) or GAMG (the same tolerances; fine grids)",
    )
    mk.add_argument("--overwrite", action="store_true")
    rn = sub.add_parser("run", help="blockMesh + interFoam, then tips.csv")
    rn.add_argument("case", type=Path)
    rn.add_argument("--np", type=int, default=1)
    rn.add_argument("--tlim", type=float, default=1500.0, help="stop interFoam after (s)")
    tp = sub.add_parser("tips", help="tips.csv from the written alpha.heavy fields")
    tp.add_argument("case", type=Path)
    tp.add_argument("--quiet", action="store_true")
    a = ap.parse_args(argv)
    if a.cmd == "make":
        if a.nx < 2 or a.ny < 2:
            fail("--nx/--ny: at least 2 cells")
        fresh_case(a.case, a.overwrite)
        spec = CaseSpec(
            a.nx, a.ny, a.max_co, a.dt, a.tau_end, a.write_every, a.sign, a.nproc, a.sides,
            a.pressure_solver,
        )  # fmt: skip
        write_case(a.case, spec)
        print(f"wrote {a.case}")
        return
    if not (a.case / "case.txt").is_file():
        fail(f"{a.case}: not a case written by 'interfoam_case.py make' (no case.txt)")
    if a.cmd == "run":
        r = run_case(a.case, a.np, a.tlim)
        print(f"interFoam: rc {r['rc']}, wall {r['wall']:.1f} s")
    rows = write_tips(a.case)
    if a.cmd == "tips" and a.quiet:
        return
    tips = tips_at(rows)
    print("tau    " + "  ".join(f"{t:>15g}" for t in TIP_TAUS))
    for k in ("spike", "bubble"):
        print(f"{k:6s} " + "  ".join(f"{v:15.4f}" for v in tips[k]))
    if len(rows):
        print(f"heavy volume {rows[0, 4]:.6f} -> {rows[-1, 4]:.6f}")


if __name__ == "__main__":
    main()
