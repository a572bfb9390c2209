"""The dam break of Martin & Moyce (1952) for OpenFOAM interFoam: write, run, read the front.

Usage::

    python benchmarks/interfoam_dambreak.py make CASE --nx 100 --ny 50 [--max-co 0.5]
        [--floor slip] [--write-every 0.05] [--overwrite]
    python benchmarks/interfoam_dambreak.py run CASE [--tlim 1800] [--json FILE]
    python benchmarks/interfoam_dambreak.py front CASE [--json FILE]

The problem is the scene ``pfem2x/scenes/dam-break.toml``: its ``[params]`` (column width
a, height n² a, g), ``[mesh] bounds`` (the closed 5a × 2.5a box), ``[phases]`` (water
ρ 1000, μ 1e-3; air ρ 1, μ 1.8e-5) and ``[time] t_end`` (T = 3.33, the last front point)
are read from the scene file, so both codes solve the same flow: a water column a × n² a at
the left wall, air above and beside it, at rest, slip on all four walls (``--floor noslip``
makes the floor no-slip). ``alpha.water`` at t = 0 is the exact area fraction of every
cell inside the column (no setFields). One 2D layer of NX × NY hexahedra.

Numerics are those of ``benchmarks/interfoam_case.py`` (the damBreak tutorial of OpenFOAM
v1912: Euler in time, MULES with ``cAlpha 1``, PIMPLE with 1 outer and 3 pressure
correctors, no momentum predictor); the step adapts to ``maxCo = maxAlphaCo = --max-co``.
``alpha.water`` is written every ``--write-every`` units of Martin & Moyce's front time
T = t sqrt(n² g / a) (a ``writeObjects`` function object).

``front`` reads every written ``alpha.water`` and writes ``front.csv`` (``t``, ``T``,
``Z``, ``tau``, ``H``, ``volume``): the front Z = x / a, the largest x of the
``alpha = 0.5`` line (crossings between cell centres along each row of cells, linear in
between), and the height H = y / (n² a), the largest y of that line in the column of cells
at the left wall, against tau = t sqrt(g / a); and it prints the numbers pfem2x's
``scene.case = "dam-break"`` reports for its runs (:class:`pfem2x.cases.DamBreakCase`):
``front_error`` (largest |Z - Z_MM| from T = 0.4 on, at the written times),
``height_error``, Z at the last front point, the mean of Z - Z_MM over Martin & Moyce's
points from T = 0.4 on, and the largest change of the water volume; with
``log.interFoam`` in the case also the number of time steps and interFoam's CPU seconds
(its last ``ExecutionTime``), and from the last fields the share of the potential energy
released that is not kinetic energy (pfem2x's ``energy_lost_final``).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
import time
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import interfoam_case  # noqa: E402  (benchmarks/interfoam_case.py: writing and running)

from pfem2x.cases import (  # noqa: E402
    MARTIN_MOYCE_FRONT,
    MARTIN_MOYCE_HEIGHT,
    DamBreakCase,
    reference_error,
)

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "pfem2x" / "scenes" / "dam-break.toml"
FLOOR_BC = interfoam_case.WALL_BC  # the floor: slip (the scene) or noslip


@dataclass(frozen=True)
class DamBreak(interfoam_case.Box):
    """The dam break as the scene states it (SI units)."""

    a: float
    n2: float
    g: float
    rho_water: float
    mu_water: float
    rho_air: float
    mu_air: float
    t_end: float

    @property
    def front_factor(self) -> float:
        """T / t = sqrt(n² g / a), Martin & Moyce's front time."""
        return math.sqrt(self.n2 * self.g / self.a)

    @property
    def height_factor(self) -> float:
        """tau / t = sqrt(g / a), Martin & Moyce's height time."""
        return math.sqrt(self.g / self.a)


def dam_break_from_scene(path: Path = SCENE) -> DamBreak:
    """Read the box, the column, the fluids and the end time from the dam-break scene."""
    s = tomllib.loads(path.read_text())
    p, ph = s["params"], s["phases"]
    (x0, y0), (x1, y1) = s["mesh"]["bounds"]
    return DamBreak(
        x0=float(x0), x1=float(x1), y0=float(y0), y1=float(y1), a=float(p["a"]),
        n2=float(p["n2"]), g=float(p["g"]), rho_water=float(ph["water"]["density"]),
        mu_water=float(ph["water"]["viscosity"]), rho_air=float(ph["air"]["density"]),
        mu_air=float(ph["air"]["viscosity"]), t_end=float(s["time"]["t_end"]),
    )  # fmt: skip


@dataclass(frozen=True)
class DamBreakSpec:
    """What ``make`` writes (also stored in the case as ``case.txt``)."""

    nx: int
    ny: int
    max_co: float = 0.5
    #: output interval in Martin & Moyce's front time T
    write_every: float = 0.05
    floor: str = "slip"


# --------------------------------------------------------------------------- writing
def initial_alpha(pb: DamBreak, nx: int, ny: int) -> np.ndarray:
    """Area fraction of every cell inside the column [x0, x0 + a] x [y0, y0 + n² a].

    Returns an (ny * nx,) array in blockMesh's cell order (x fastest); exact (the column
    is a rectangle).
    """
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    fx = np.clip((pb.a - dx * np.arange(nx)) / dx, 0.0, 1.0)
    fy = np.clip((pb.n2 * pb.a - dy * np.arange(ny)) / dy, 0.0, 1.0)
    return (fy[:, None] * fx[None, :]).ravel()


def write_case(case: Path, spec: DamBreakSpec, pb: DamBreak | None = None) -> None:
    """Write a complete interFoam case for ``spec`` into the folder ``case``."""
    if spec.floor not in FLOOR_BC:
        raise ValueError(f"floor {spec.floor!r}: one of {sorted(FLOOR_BC)}")
    pb = pb or dam_break_from_scene()
    case.mkdir(parents=True, exist_ok=True)
    every = spec.write_every / pb.front_factor
    end = math.ceil(pb.t_end / every - 1e-9) * every
    interfoam_case.write_block_mesh(case, pb, spec.nx, spec.ny)
    dy = (pb.y1 - pb.y0) / spec.ny
    step = interfoam_case.adaptive_step(1e-3 * dy, spec.max_co, every)
    history = interfoam_case.write_objects(
        "waterHistory", "alpha.water", "adjustableRunTime", every
    )
    interfoam_case.write_control(case, end, step, history, time_precision=10)
    interfoam_case.write_numerics(case, "water")
    interfoam_case.write_fluids(
        case, ("water", pb.rho_water, pb.mu_water), ("air", pb.rho_air, pb.mu_air), pb.g
    )
    u_bc = dict.fromkeys(interfoam_case.SIDES, "type slip;") | {"bottom": FLOOR_BC[spec.floor]}
    interfoam_case.write_fields(case, "water", initial_alpha(pb, spec.nx, spec.ny), u_bc)
    (case / "case.txt").write_text(repr(asdict(spec) | asdict(pb)) + "\n")


# --------------------------------------------------------------------------- reading
def _last_crossing(a: np.ndarray, c0: float, step: float) -> float:
    """Largest coordinate where the rows of ``a - 0.5`` change sign along axis 1.

    ``a`` holds values at the cell centres ``c0 + step (i + 1/2)``; the crossing between
    two centres is linear. NaN if no row crosses.
    """
    lo, hi = a[:, :-1] - 0.5, a[:, 1:] - 0.5
    cross = (lo < 0.0) != (hi < 0.0)
    if not cross.any():
        return math.nan
    centres = c0 + step * (np.arange(a.shape[1] - 1) + 0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = centres[None, :] + step * lo / (lo - hi)
    return float(x[cross].max())


def front_height(alpha: np.ndarray, pb: DamBreak, nx: int, ny: int) -> tuple[float, float]:
    """The front Z = x / a and the height H = y / (n² a) of one ``alpha.water`` field."""
    a = alpha.reshape(ny, nx)
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    x = _last_crossing(a, pb.x0, dx)
    y = _last_crossing(a[:, :1].T, pb.y0, dy)
    return (x - pb.x0) / pb.a, (y - pb.y0) / (pb.n2 * pb.a)


def case_front(case: Path) -> np.ndarray:
    """Rows (t, T, Z, tau, H, volume) for every written ``alpha.water`` of a case."""
    info = interfoam_case.eval_case_txt(case)
    pb = DamBreak(**{k: info[k] for k in DamBreak.__dataclass_fields__})
    nx, ny = int(info["nx"]), int(info["ny"])
    cell = (pb.x1 - pb.x0) / nx * (pb.y1 - pb.y0) / ny
    rows = []
    for t, d in interfoam_case.time_dirs(case):
        a = interfoam_case.read_internal_scalar(d / "alpha.water")
        if t == 0.0 and a is None:
            a = initial_alpha(pb, nx, ny)
        if a is None or a.size != nx * ny:
            continue
        z, h = front_height(a, pb, nx, ny)
        rows.append((t, t * pb.front_factor, z, t * pb.height_factor, h, float(a.sum() * cell)))
    return np.array(rows, dtype=float).reshape(-1, 6)


def energy_lost(case: Path) -> float | None:
    """pfem2x's ``energy_lost_final`` of a case: 1 - (kinetic energy at the last written
    time) / (potential energy released since t = 0), from its ``U`` and ``alpha.water``
    (cell-centre values, rho = alpha rho_water + (1 - alpha) rho_air); None without them."""
    info = interfoam_case.eval_case_txt(case)
    pb = DamBreak(**{k: info[k] for k in DamBreak.__dataclass_fields__})
    nx, ny = int(info["nx"]), int(info["ny"])
    t, last = interfoam_case.time_dirs(case)[-1]
    alpha = interfoam_case.read_internal_scalar(last / "alpha.water")
    u = interfoam_case.read_internal_vector(last / "U", nx * ny)
    if t <= 0.0 or alpha is None or u is None or len(u) != nx * ny:
        return None
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    y = np.repeat(pb.y0 + dy * (np.arange(ny) + 0.5), nx)

    def rho(a: np.ndarray) -> np.ndarray:
        return a * pb.rho_water + (1.0 - a) * pb.rho_air

    released = pb.g * dx * dy * float(np.sum((rho(initial_alpha(pb, nx, ny)) - rho(alpha)) * y))
    if not released > 0.0:
        return None
    kinetic = 0.5 * dx * dy * float(np.sum(rho(alpha) * (u[:, 0] ** 2 + u[:, 1] ** 2)))
    return 1.0 - kinetic / released


def summarise(rows: np.ndarray) -> dict[str, float]:
    """``front_error``, ``height_error`` (pfem2x's definitions), Z at the last front point,
    the mean of Z - Z_MM from T = 0.4 on and the largest relative water-volume change."""
    front, height = rows[:, [1, 2]], rows[:, [3, 4]]
    ref = MARTIN_MOYCE_FRONT[MARTIN_MOYCE_FRONT[:, 0] >= DamBreakCase.FRONT_FROM]
    reach = ref[ref[:, 0] <= front[-1, 0] + 1e-9]
    t_last = float(MARTIN_MOYCE_FRONT[-1, 0])
    return {
        "front_error": reference_error(front, MARTIN_MOYCE_FRONT, DamBreakCase.FRONT_FROM),
        "height_error": reference_error(height, MARTIN_MOYCE_HEIGHT),
        "Z_last": float(np.interp(t_last, front[:, 0], front[:, 1]))
        if front[-1, 0] >= t_last - 1e-9
        else math.nan,
        "mean_front_lead": float(np.mean(np.interp(reach[:, 0], *front.T) - reach[:, 1])),
        "volume_change_max": float(np.abs(rows[:, 5] / rows[0, 5] - 1.0).max()),
        "T_end": float(front[-1, 0]),
    }


def log_facts(case: Path) -> dict[str, Any]:
    """interFoam's time steps and its last ``ExecutionTime`` (CPU s) from ``log.interFoam``."""
    log = case / "log.interFoam"
    if not log.is_file():
        return {}
    text = log.read_text()
    cpu = re.findall(r"^ExecutionTime = ([0-9.eE+-]+) s", text, flags=re.M)
    out: dict[str, Any] = {"steps": len(re.findall(r"^Time = ", text, flags=re.M))}
    return out | ({"cpu_s": float(cpu[-1])} if cpu else {})


# --------------------------------------------------------------------------- command line
def main(argv: list[str] | None = None) -> None:
    """Command line: ``make``, ``run`` and ``front`` (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    mk = sub.add_parser("make", help="write a case folder")
    mk.add_argument("case", type=Path)
    mk.add_argument("--nx", type=int, required=True)
    mk.add_argument("--ny", type=int, required=True)
    mk.add_argument("--max-co", type=float, default=0.5, help="maxCo = maxAlphaCo")
    mk.add_argument("--write-every", type=float, default=0.05, help="output interval in T")
    mk.add_argument("--floor", choices=sorted(FLOOR_BC), default="slip")
    mk.add_argument("--overwrite", action="store_true")
    rn = sub.add_parser("run", help="blockMesh + interFoam, then front.csv")
    rn.add_argument("case", type=Path)
    rn.add_argument("--tlim", type=float, default=1800.0, help="stop interFoam after (s)")
    fr = sub.add_parser("front", help="front.csv from the written alpha.water fields")
    fr.add_argument("case", type=Path)
    for p in (rn, fr):
        p.add_argument("--json", type=Path, help="also write the summary as JSON")
    a = ap.parse_args(argv)
    fail = interfoam_case.fail
    if a.cmd == "make":
        if a.nx < 2 or a.ny < 2:
            fail("--nx/--ny: at least 2 cells")
        if not (a.max_co > 0.0 and a.write_every > 0.0):
            fail("--max-co/--write-every: positive numbers")
        interfoam_case.fresh_case(a.case, a.overwrite)
        write_case(a.case, DamBreakSpec(a.nx, a.ny, a.max_co, a.write_every, a.floor))
        print(f"wrote {a.case}")
        return
    if not (a.case / "case.txt").is_file():
        fail(f"{a.case}: not a case written by 'interfoam_dambreak.py make' (no case.txt)")
    out: dict[str, Any] = {}
    if a.cmd == "run" and not interfoam_case.FOAM_BASHRC.is_file():
        fail(f"{interfoam_case.FOAM_BASHRC}: OpenFOAM not found (apt-get install openfoam)")
    if a.cmd == "run":
        t0 = time.perf_counter()
        try:
            out = interfoam_case.run_case(a.case, 1, a.tlim)
        except RuntimeError as e:  # blockMesh failed: its log is named
            fail(str(e))
        print(f"interFoam: rc {out['rc']}, wall {time.perf_counter() - t0:.1f} s")
    rows = case_front(a.case)
    if len(rows) < 2:
        fail(f"{a.case}: fewer than two written alpha.water fields")
    np.savetxt(a.case / "front.csv", rows, delimiter=",", fmt="%.8g",
               header="t,T,Z,tau,H,volume", comments="")  # fmt: skip
    out |= log_facts(a.case) | summarise(rows)
    lost = energy_lost(a.case)
    if lost is not None:
        out["energy_lost_final"] = lost
    for k, v in out.items():
        print(f"{k:18s} {v:.4g}" if isinstance(v, float) else f"{k:18s} {v}")
    if a.json:
        a.json.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
