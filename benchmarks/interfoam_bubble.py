"""Hysing's rising bubble (test case 1) for OpenFOAM interFoam: write, run, post-process.

Usage::

    python benchmarks/interfoam_bubble.py make CASE --n 40 [--max-co 0.5] [--max-dt DT]
        [--capillary C] [--write-every 0.02] [--t-end 3]
    python benchmarks/interfoam_bubble.py run CASE [--tlim 1800]
    python benchmarks/interfoam_bubble.py post CASE
    python benchmarks/interfoam_bubble.py bench --n 40 80 [--capillary C] [--work DIR] [--out DIR]
    python benchmarks/interfoam_bubble.py curves SERIES.csv [SERIES.csv ...]

The problem is the scene ``pfem2x/scenes/rising-bubble.toml`` (Hysing et al. 2009, test
case 1): its ``[params]`` (R, xc, yc, g, sigma), ``[phases]`` (densities, dynamic
viscosities), ``[mesh] bounds`` and the wall conditions of ``[flow]`` are read from the
scene file, so both codes solve the same flow: domain 1 x 2, bubble R = 0.25 at
(0.5, 0.5), rho 1000 outside / 100 inside, mu 10 / 1, g = 0.98, sigma = 24.5, no-slip top
and bottom, free slip on the sides, t in [0, 3].

Case: one 2D layer of N x 2N hexahedra (h = 1/N, ``empty`` front and back). Phase 1 is the
bubble (``alpha.bubble``); its initial field is the exact area fraction of every cell
inside the circle (closed-form integral of the clipped chord length, written as a
nonuniform list: no setFields). Numerics are those of the damBreak tutorial of OpenFOAM
v1912 (``apt-get install openfoam``), as in ``benchmarks/interfoam_case.py``: Euler in
time, MULES (semi-implicit, ``MULESCorr yes``, 2 alpha correctors, ``cAlpha 1``, vanLeer),
PIMPLE with 1 outer and 3 pressure correctors, no momentum predictor; adaptive step
``maxCo = maxAlphaCo = --max-co`` (default 0.5), at most ``--max-dt`` (default the write
interval) and, with ``--capillary C``, at most C times the explicit capillary limit
sqrt(rho_mean h³ / (2 pi sigma)) (:func:`capillary_dt`): interFoam itself has no capillary
time-step limit.

Output: ``alpha.bubble`` and ``U`` every ``--write-every`` time units (a ``writeObjects``
function object; all fields at the end) and, every time step, the bubble volume
(``volIntegrate`` of ``alpha.bubble``) and the alpha-weighted mean velocity (a
``volFieldValue`` ``weightedVolAverage`` of ``U`` weighted by ``alpha.bubble``) in
``postProcessing/``.

``post`` computes from the written fields, with alpha_b = ``alpha.bubble`` and V the cell
volumes: centroid height y_c = sum(alpha_b y V) / sum(alpha_b V), rise velocity
u_c = sum(alpha_b u_y V) / sum(alpha_b V), circularity = pi d_a / P_b (d_a the diameter of
the circle of area sum(alpha_b V), P_b the length of the alpha_b = 0.5 contour of the
cell-centre values, marching squares by ``contourpy``), and writes ``series.csv`` (t,
centroid_y, rise_velocity, circularity, area) and ``result.json``: y_c(3), max u_c and
min circularity with their times (u_c also from the per-step function object), relative
errors against the TP2D values of ``docs/data/rising-bubble/hysing2009.csv``, the
solver's ClockTime (wall) and ExecutionTime (CPU) at the end, the number of time steps
and the largest Courant number.

``bench`` runs make, run and post for every ``--n`` in turn (serial interFoam, one
thread), records the load average before and after every run and writes
``result_n<N>.json``, ``series_n<N>.csv`` and ``results.md`` into ``--out`` (default
``docs/data/rising-bubble/interfoam``; with ``--capillary C`` the names end in ``_cap<C>``).

``curves`` prints, for ``series.csv`` files (written by ``post`` or stored by ``bench``),
the largest differences of centroid height, rise velocity and circularity to the group
MooNMD's series over 0 <= t <= 3: pfem2x's metrics ``*_curve_error``
(:func:`pfem2x.cases.curve_errors`), at the series' output times.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import shutil
import sys
import time
import tomllib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "pfem2x" / "scenes" / "rising-bubble.toml"
REFERENCE = ROOT / "docs" / "data" / "rising-bubble" / "hysing2009.csv"
OUT_DIR = ROOT / "docs" / "data" / "rising-bubble" / "interfoam"
sys.path.insert(0, str(Path(__file__).resolve().parent))
import interfoam_case  # noqa: E402  (benchmarks/interfoam_case.py: _foam, _foam_file)

QUANTITIES = ("centroid_y_final", "rise_velocity_max", "circularity_min")


@dataclass(frozen=True)
class Bubble(interfoam_case.Box):
    """The rising-bubble problem as the scene states it."""

    R: float
    xc: float
    yc: float
    g: float
    sigma: float
    rho_bubble: float
    mu_bubble: float
    rho_outer: float
    mu_outer: float
    left: str
    right: str
    bottom: str
    top: str
    scene_t_end: float


def bubble_from_scene(path: Path = SCENE) -> Bubble:
    """Read the rising-bubble problem (test case 1) from the scene file."""
    s = tomllib.loads(path.read_text())
    p, ph, fl = s["params"], s["phases"], s["flow"]
    (x0, y0), (x1, y1) = s["mesh"]["bounds"]
    return Bubble(
        x0=float(x0), x1=float(x1), y0=float(y0), y1=float(y1), R=float(p["R"]),
        xc=float(p["xc"]), yc=float(p["yc"]), g=float(p["g"]), sigma=float(p["sigma"]),
        rho_bubble=float(ph["bubble"]["density"]), mu_bubble=float(ph["bubble"]["viscosity"]),
        rho_outer=float(ph["outer"]["density"]), mu_outer=float(ph["outer"]["viscosity"]),
        left=fl["left"], right=fl["right"], bottom=fl["bottom"], top=fl["top"],
        scene_t_end=float(s["time"]["t_end"]),
    )  # fmt: skip


@dataclass(frozen=True)
class BubbleSpec:
    """What ``make`` writes (also stored in the case as ``case.txt``)."""

    n: int
    max_co: float = 0.5
    max_dt: float | None = None
    write_every: float = 0.02
    t_end: float = 3.0
    capillary: float | None = None


def capillary_dt(pb: Bubble, n: int) -> float:
    """The explicit capillary time-step limit sqrt(rho_mean h³ / (2 pi sigma)) for h = 1/N.

    rho_mean is the mean of the two densities, h the cell width (x0 - x1) / N.
    """
    h = (pb.x1 - pb.x0) / n
    rho = 0.5 * (pb.rho_bubble + pb.rho_outer)
    return math.sqrt(rho * h**3 / (2.0 * math.pi * pb.sigma))


# --------------------------------------------------------------------------- initial field
def _clip_integral(y: np.ndarray, a: np.ndarray, b: np.ndarray, R: float) -> np.ndarray:
    """Integral over x in [a, b] (inside [-R, R]) of clip(y, -s(x), s(x)), s = sqrt(R² - x²).

    Where |x| < w = sqrt(R² - y²) the clip is y; elsewhere it is sign(y) s(x), whose
    antiderivative is (x s + R² asin(x / R)) / 2.
    """
    w = np.sqrt(np.maximum(R * R - y * y, 0.0))

    def prim(x: np.ndarray) -> np.ndarray:
        x = np.clip(x, -R, R)
        return 0.5 * (x * np.sqrt(np.maximum(R * R - x * x, 0.0)) + R * R * np.arcsin(x / R))

    inner = np.maximum(np.minimum(b, w) - np.maximum(a, -w), 0.0)
    lo_b = np.minimum(b, -w)  # [a, -w]
    hi_a = np.maximum(a, w)  # [w, b]
    outer = np.where(lo_b > a, prim(lo_b) - prim(a), 0.0) + np.where(
        b > hi_a, prim(b) - prim(hi_a), 0.0
    )
    return y * inner + np.sign(y) * outer


def initial_alpha(pb: Bubble, n: int) -> np.ndarray:
    """Exact area fraction of every cell inside the bubble, in blockMesh order (x fastest).

    The area of the disc inside a cell [xa, xb] x [ya, yb] is the integral over x of the
    chord inside [ya, yb], i.e. of clip(yb, -s, s) - clip(ya, -s, s) with the disc centred
    at the origin: closed form (:func:`_clip_integral`).
    """
    nx, ny = n, 2 * n
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    xa = pb.x0 + dx * np.arange(nx)[None, :] - pb.xc
    ya = pb.y0 + dy * np.arange(ny)[:, None] - pb.yc
    a, b = np.clip(xa, -pb.R, pb.R), np.clip(xa + dx, -pb.R, pb.R)
    area = _clip_integral(ya + dy, a, b, pb.R) - _clip_integral(ya, a, b, pb.R)
    return np.clip(area / (dx * dy), 0.0, 1.0).ravel()


# --------------------------------------------------------------------------- writing
def write_case(case: Path, spec: BubbleSpec, pb: Bubble | None = None) -> None:
    """Write a complete interFoam case for ``spec`` into the folder ``case``."""
    pb = pb or bubble_from_scene()
    for side in ("left", "right", "bottom", "top"):
        if getattr(pb, side) not in interfoam_case.WALL_BC:
            raise ValueError(f"flow.{side} = {getattr(pb, side)!r}: only noslip and slip")
    case.mkdir(parents=True, exist_ok=True)
    nx, ny = spec.n, 2 * spec.n
    end = math.ceil(spec.t_end / spec.write_every - 1e-9) * spec.write_every
    interfoam_case.write_block_mesh(case, pb, nx, ny)
    max_dt = spec.max_dt if spec.max_dt is not None else spec.write_every
    dy = (pb.y1 - pb.y0) / ny
    history = interfoam_case.write_objects(
        "bubbleHistory", "alpha.bubble U", "adjustableRunTime", spec.write_every
    )
    step = interfoam_case.adaptive_step(0.1 * dy, spec.max_co, max_dt)
    interfoam_case.write_control(case, end, step, history + """\
    bubbleVolume
    {
        type volFieldValue;
        libs ("libfieldFunctionObjects.so");
        fields (alpha.bubble);
        operation volIntegrate;
        regionType all;
        writeFields false;
        log false;
        writeControl timeStep;
        writeInterval 1;
    }
    bubbleVelocity
    {
        type volFieldValue;
        libs ("libfieldFunctionObjects.so");
        fields (U);
        operation weightedVolAverage;
        weightField alpha.bubble;
        regionType all;
        writeFields false;
        log false;
        writeControl timeStep;
        writeInterval 1;
    }
""")  # fmt: skip
    interfoam_case.write_numerics(case, "bubble")
    interfoam_case.write_fluids(
        case, ("bubble", pb.rho_bubble, pb.mu_bubble), ("outer", pb.rho_outer, pb.mu_outer),
        pb.g, pb.sigma,
    )  # fmt: skip
    u_bc = {w: interfoam_case.WALL_BC[getattr(pb, w)] for w in interfoam_case.SIDES}
    interfoam_case.write_fields(case, "bubble", initial_alpha(pb, spec.n), u_bc)
    (case / "case.txt").write_text(repr(asdict(spec) | asdict(pb)) + "\n")


# --------------------------------------------------------------------------- running
def run_case(case: Path, tlim: float = 1800.0) -> dict[str, float | int]:
    """blockMesh + serial interFoam; return code and wall seconds of interFoam."""
    if interfoam_case._foam("blockMesh", case, "log.blockMesh") != 0:
        raise RuntimeError(f"blockMesh failed: {case / 'log.blockMesh'}")
    t0 = time.perf_counter()
    rc = interfoam_case._foam("interFoam", case, "log.interFoam", timeout=tlim)
    wall = time.perf_counter() - t0
    (case / "wallclock.txt").write_text(f"np=1 rc={rc} wall_s={wall:.3f}\n")
    return {"rc": rc, "wall": wall}


# --------------------------------------------------------------------------- reading
def read_internal_alpha(path: Path) -> np.ndarray | None:
    """The internalField of an ASCII volScalarField (plain or ``.gz``); None if absent."""
    return interfoam_case.read_internal_scalar(path)


def contour_length(z: np.ndarray, xs: np.ndarray, ys: np.ndarray, level: float = 0.5) -> float:
    """Total length of the ``level`` iso-lines of ``z`` (ny, nx) on the grid ``xs`` x ``ys``."""
    import contourpy  # noqa: PLC0415  (a dependency of matplotlib)

    gen = contourpy.contour_generator(xs, ys, z, line_type="Separate")
    return float(sum(np.hypot(*np.diff(ln, axis=0).T).sum() for ln in gen.lines(level)))


def geometry(pb: Bubble, n: int, alpha: np.ndarray, u: np.ndarray) -> dict[str, float]:
    """Centroid, rise velocity, circularity and area of the bubble from cell values."""
    nx, ny = n, 2 * n
    dx, dy = (pb.x1 - pb.x0) / nx, (pb.y1 - pb.y0) / ny
    xs = pb.x0 + dx * (np.arange(nx) + 0.5)
    ys = pb.y0 + dy * (np.arange(ny) + 0.5)
    a = alpha.reshape(ny, nx)
    area = float(a.sum()) * dx * dy
    w = float(a.sum())
    yc = float((a * ys[:, None]).sum()) / w
    uc = float((a * u[:, 1].reshape(ny, nx)).sum()) / w
    perim = contour_length(a, xs, ys)
    circ = 2.0 * math.sqrt(math.pi * area) / perim if perim > 0 else math.nan
    return {"centroid_y": yc, "rise_velocity": uc, "circularity": circ, "area": area}


def series(case: Path) -> np.ndarray:
    """Rows (t, centroid_y, rise_velocity, circularity, area) of every written time."""
    info = read_case_txt(case)
    pb = Bubble(**{k: info[k] for k in Bubble.__dataclass_fields__})
    n = int(info["n"])
    rows = []
    for t, d in interfoam_case.time_dirs(case):
        a = read_internal_alpha(d / "alpha.bubble")
        u = interfoam_case.read_internal_vector(d / "U", 2 * n * n)
        if a is None or u is None or a.size != 2 * n * n:
            continue
        g = geometry(pb, n, a, u)
        rows.append((t, g["centroid_y"], g["rise_velocity"], g["circularity"], g["area"]))
    return np.array(rows, dtype=float).reshape(-1, 5)


def read_case_txt(case: Path) -> dict[str, Any]:
    """The parameters ``make`` stored in ``case.txt``."""
    import ast  # noqa: PLC0415

    return ast.literal_eval((case / "case.txt").read_text())


def step_velocity(case: Path) -> np.ndarray | None:
    """Rows (t, u_c) of the per-step ``bubbleVelocity`` function object, or None."""
    files = sorted((case / "postProcessing" / "bubbleVelocity").glob("*/volFieldValue*.dat"))
    if not files:
        return None
    rows = []
    for line in files[0].read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        parts = line.replace("(", " ").replace(")", " ").split()
        rows.append((float(parts[0]), float(parts[2])))
    return np.array(rows, dtype=float).reshape(-1, 2) if rows else None


def step_volume(case: Path) -> np.ndarray | None:
    """Rows (t, bubble volume) of the per-step ``bubbleVolume`` function object, or None."""
    files = sorted((case / "postProcessing" / "bubbleVolume").glob("*/volFieldValue*.dat"))
    if not files:
        return None
    rows = [
        (float(p[0]), float(p[1]))
        for p in (ln.split() for ln in files[0].read_text().splitlines())
        if p and not p[0].startswith("#")
    ]
    return np.array(rows, dtype=float).reshape(-1, 2) if rows else None


_TIME = re.compile(r"^Time = (\S+)\s*$", re.M)
_EXEC = re.compile(r"^ExecutionTime = (\S+) s\s+ClockTime = (\S+) s", re.M)
_CO = re.compile(r"^Courant Number mean: \S+ max: (\S+)", re.M)
_DT = re.compile(r"^deltaT = (\S+)", re.M)


def parse_log(text: str) -> dict[str, Any]:
    """Steps, last time, CPU (ExecutionTime) and wall (ClockTime) at the end, max Courant."""
    times = [float(m.group(1)) for m in _TIME.finditer(text)]
    execs = [(float(m.group(1)), float(m.group(2))) for m in _EXEC.finditer(text)]
    cos = [float(m.group(1)) for m in _CO.finditer(text)]
    dts = [float(m.group(1)) for m in _DT.finditer(text)]
    out: dict[str, Any] = {"steps": len(times), "t_last": times[-1] if times else 0.0}
    if execs:
        out["cpu"], out["wall"] = execs[-1]
    if cos:
        out["courant_max"] = max(cos)
    if dts:
        out["dt_min"], out["dt_max"] = min(dts), max(dts)
    out["ended"] = bool(re.search(r"^End\s*$", text, re.M))
    return out


# --------------------------------------------------------------------------- results
def reference(path: Path = REFERENCE) -> dict[str, tuple[float, float]]:
    """TP2D values of test case 1: quantity -> (value, time)."""
    with open(path) as f:
        return {
            r["quantity"]: (float(r["value"]), float(r["time"]))
            for r in csv.DictReader(f)
            if r["case"] == "1" and r["group"] == "TP2D"
        }


def summarise(case: Path) -> dict[str, Any]:
    """Benchmark quantities, errors, cost of a finished case (writes ``series.csv``)."""
    info = read_case_txt(case)
    rows = series(case)
    np.savetxt(case / "series.csv", rows, delimiter=",", fmt="%.8g",
               header="t,centroid_y,rise_velocity,circularity,area", comments="")  # fmt: skip
    logf = case / "log.interFoam"
    log = parse_log(logf.read_text(errors="replace")) if logf.exists() else {}
    res: dict[str, Any] = {
        "n": int(info["n"]), "h": f"1/{int(info['n'])}", "cells": [info["n"], 2 * info["n"]],
        "max_co": info["max_co"], "max_dt": info["max_dt"] or info["write_every"],
        "capillary": info.get("capillary"),
        "capillary_dt": capillary_dt(Bubble(**{k: info[k] for k in Bubble.__dataclass_fields__}),
                                     int(info["n"])),
        "write_every": info["write_every"], **log,
    }  # fmt: skip
    t_end = float(info["t_end"])
    if len(rows) < 2 or rows[-1, 0] < t_end - 1e-6:
        res["status"] = f"failed (fields up to t = {rows[-1, 0] if len(rows) else 0:g})"
        return res
    t = rows[:, 0]
    res["status"] = "ok"
    res["centroid_y_final"] = float(np.interp(t_end, t, rows[:, 1]))
    k = int(np.argmax(rows[:, 2]))
    res["rise_velocity_max"], res["rise_velocity_max_time"] = float(rows[k, 2]), float(t[k])
    k = int(np.argmin(rows[:, 3]))
    res["circularity_min"], res["circularity_min_time"] = float(rows[k, 3]), float(t[k])
    area = rows[:, 4]
    res["area_change_max"] = float(np.abs(area / area[0] - 1.0).max())
    sv = step_velocity(case)
    if sv is not None and len(sv):
        k = int(np.argmax(sv[:, 1]))
        res["rise_velocity_max_step"] = float(sv[k, 1])
        res["rise_velocity_max_step_time"] = float(sv[k, 0])
    vol = step_volume(case)
    if vol is not None and len(vol):
        v0 = float(vol[0, 1])  # the volume after the first step
        res["volume_change_max_step"] = float(np.abs(vol[:, 1] / v0 - 1.0).max())
    ref = reference()
    for q in QUANTITIES:
        res[f"{q}_rel_error"] = abs(res[q] - ref[q][0]) / ref[q][0]
    return res


def markdown(results: list[dict[str, Any]], head: str = "") -> str:
    """The result table (one row per run, TP2D last)."""
    ref = reference()
    lines = [
        "| h | steps | Δt | max Co | y_c(t = 3) | error | max u_c (t) | error "
        "| min circularity (t) | error | bubble volume | CPU s | wall s | load before → after |",
        "|---|---:|---|---:|---|---:|---|---:|---|---:|---:|---:|---:|---|",
    ]

    def pct(v: float) -> str:
        return f"{100 * v:.2g} %"

    for r in results:
        if r.get("status") != "ok":
            lines.append(f"| {r['h']} | {r.get('steps', '–')} | | | {r.get('status')} |" + " |" * 9)
            continue
        load = r.get("load_before", [math.nan])[0], r.get("load_after", [math.nan])[0]
        lines.append(
            f"| {r['h']} | {r['steps']} "
            f"| {r.get('dt_min', math.nan):.2g}–{r.get('dt_max', math.nan):.2g} "
            f"| {r.get('courant_max', math.nan):.2f} "
            f"| {r['centroid_y_final']:.4f} | {pct(r['centroid_y_final_rel_error'])} "
            f"| {r['rise_velocity_max']:.4f} ({r['rise_velocity_max_time']:.2f}) "
            f"| {pct(r['rise_velocity_max_rel_error'])} "
            f"| {r['circularity_min']:.4f} ({r['circularity_min_time']:.2f}) "
            f"| {pct(r['circularity_min_rel_error'])} | {r['area_change_max']:.1e} "
            f"| {r.get('cpu', math.nan):.1f} | {r.get('wall', math.nan):.1f} "
            f"| {load[0]:.2f} → {load[1]:.2f} |"
        )
    c, u, y = ref["circularity_min"], ref["rise_velocity_max"], ref["centroid_y_final"]
    lines.append(
        f"| TP2D | | | | {y[0]:.4f} | | {u[0]:.4f} ({u[1]:.4f}) | | {c[0]:.4f} ({c[1]:.4f}) "
        "| | | | | |"
    )
    notes = [
        f"- h = {r['h']}: max u_c from every time step (function object): "
        f"{r['rise_velocity_max_step']:.4f} at t = {r['rise_velocity_max_step_time']:.3f}; "
        f"capillary limit {r['capillary_dt']:.2g}."
        for r in results
        if r.get("status") == "ok" and "rise_velocity_max_step" in r
    ]
    return head + "\n".join(lines) + ("\n\n" + "\n".join(notes) if notes else "") + "\n"


def curve_table(paths: list[Path], fail: Any) -> str:
    """Markdown table of the curve errors of ``series.csv`` files against MooNMD's series.

    Parameters
    ----------
    paths
        Files with the columns ``t, centroid_y, rise_velocity, circularity`` (header line).
    fail
        Called with a message for a missing or unreadable file (does not return).
    """
    from pfem2x.cases import BUBBLE_SERIES, curve_errors, moonmd_series

    ref = moonmd_series(1)
    lines = [
        "| series | max \\|Δy_c\\| | max \\|Δu_c\\| | max \\|Δcircularity\\| |",
        "|---|---:|---:|---:|",
    ]
    for path in paths:
        try:
            d = np.genfromtxt(path, delimiter=",", names=True)
            vals = {k: np.atleast_1d(d[k]) for k in BUBBLE_SERIES}
            t = np.atleast_1d(d["t"])
        except (OSError, ValueError) as e:
            fail(f"{path}: {e}")
        e = curve_errors(t, vals, ref)
        cells = " | ".join(f"{e[f'{k}_curve_error']:.4f}" for k in BUBBLE_SERIES)
        lines.append(f"| {path.name} | {cells} |")
    return "\n".join(lines) + "\n"


def loadavg() -> list[float]:
    """The 1, 5 and 15 minute load averages."""
    return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]


# --------------------------------------------------------------------------- command line
def main(argv: list[str] | None = None) -> None:
    """Command line: ``make``, ``run``, ``post`` and ``bench`` (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)

    def case_opts(p: argparse.ArgumentParser) -> None:
        p.add_argument("--max-co", type=float, default=0.5, help="maxCo = maxAlphaCo")
        p.add_argument("--max-dt", type=float, help="maxDeltaT (default: --write-every)")
        p.add_argument("--capillary", type=float, metavar="C",
                       help="maxDeltaT at most C x the capillary limit (capillary_dt)")  # fmt: skip
        p.add_argument("--write-every", type=float, default=0.02, help="field output interval")
        p.add_argument("--t-end", type=float, default=None, help="default: the scene's")

    cv = sub.add_parser("curves", help="curve errors of series.csv files against MooNMD")
    cv.add_argument("series", type=Path, nargs="+")
    mk = sub.add_parser("make", help="write a case folder")
    mk.add_argument("case", type=Path)
    mk.add_argument("--n", type=int, required=True, help="h = 1/N: N x 2N cells")
    case_opts(mk)
    mk.add_argument("--overwrite", action="store_true")
    rn = sub.add_parser("run", help="blockMesh + interFoam, then post")
    rn.add_argument("case", type=Path)
    rn.add_argument("--tlim", type=float, default=1800.0, help="stop interFoam after (s)")
    pp = sub.add_parser("post", help="series.csv and result.json from the written fields")
    pp.add_argument("case", type=Path)
    bn = sub.add_parser("bench", help="make + run + post for every --n; tables into --out")
    bn.add_argument("--n", type=int, nargs="+", default=[40, 80])
    case_opts(bn)
    bn.add_argument("--work", type=Path, default=ROOT / "benchmarks/_work/interfoam_bubble")
    bn.add_argument("--out", type=Path, default=OUT_DIR)
    bn.add_argument("--tlim", type=float, default=1800.0, help="stop interFoam after (s)")
    bn.add_argument("--keep", action="store_true", help="keep the time folders of the cases")
    a = ap.parse_args(argv)
    fail = interfoam_case.fail

    def spec_of(n: int) -> BubbleSpec:
        if n < 4:
            fail("--n: at least 4 cells across")
        if min(a.max_co, a.write_every, a.max_dt or 1.0, a.capillary or 1.0) <= 0:
            fail("--max-co, --max-dt, --capillary, --write-every: must be positive")
        try:
            pb = bubble_from_scene()
        except (OSError, KeyError, tomllib.TOMLDecodeError) as e:
            fail(f"{SCENE}: {e}")
        t_end = pb.scene_t_end if a.t_end is None else a.t_end
        max_dt = a.max_dt
        if a.capillary is not None:
            max_dt = min(max_dt or a.write_every, a.capillary * capillary_dt(pb, n))
        return BubbleSpec(n, a.max_co, max_dt, a.write_every, t_end, a.capillary)

    if a.cmd == "curves":
        print(curve_table(a.series, fail), end="")
        return
    if a.cmd in ("run", "bench") and not interfoam_case.FOAM_BASHRC.is_file():
        fail(f"{interfoam_case.FOAM_BASHRC}: OpenFOAM not found (apt-get install openfoam)")
    if a.cmd == "make":
        spec = spec_of(a.n)
        interfoam_case.fresh_case(a.case, a.overwrite)
        write_case(a.case, spec)
        print(f"wrote {a.case}")
        return
    if a.cmd in ("run", "post"):
        if not (a.case / "case.txt").is_file():
            fail(f"{a.case}: not a case written by 'interfoam_bubble.py make' (no case.txt)")
        if a.cmd == "run":
            r = run_case(a.case, a.tlim)
            print(f"interFoam: rc {r['rc']}, wall {r['wall']:.1f} s")
        res = summarise(a.case)
        (a.case / "result.json").write_text(json.dumps(res, indent=1) + "\n")
        print(markdown([res]))
        return

    specs = [spec_of(n) for n in a.n]
    tag = "" if a.capillary is None else f"_cap{a.capillary:g}"
    results = []
    a.out.mkdir(parents=True, exist_ok=True)
    start = time.strftime("%Y-%m-%d %H:%M %Z")
    for spec in specs:
        case = a.work / f"bubble_n{spec.n}{tag}"
        if case.exists():
            shutil.rmtree(case)
        write_case(case, spec)
        load0 = loadavg()
        r = run_case(case, a.tlim)
        load1 = loadavg()
        res = summarise(case) | {"load_before": load0, "load_after": load1,
                                 "process_wall": r["wall"], "rc": r["rc"]}  # fmt: skip
        (case / "result.json").write_text(json.dumps(res, indent=1) + "\n")
        (a.out / f"result_n{spec.n}{tag}.json").write_text(json.dumps(res, indent=1) + "\n")
        shutil.copy(case / "series.csv", a.out / f"series_n{spec.n}{tag}.csv")
        results.append(res)
        print(f"n = {spec.n}: {res['status']}, {res.get('steps')} steps, "
              f"CPU {res.get('cpu', math.nan):.1f} s, load {load0[0]} -> {load1[0]}",
              flush=True)  # fmt: skip
        if not a.keep:
            for _t, d in interfoam_case.time_dirs(case):
                if d.name != "0":
                    shutil.rmtree(d)
    cmd = " ".join(["python benchmarks/interfoam_bubble.py", *(argv or sys.argv[1:])])
    head = (
        f"`{cmd}` — {start}, OpenFOAM v1912 interFoam, serial, maxCo = maxAlphaCo = "
        f"{a.max_co:g}, maxDeltaT "
        + (
            f"{a.capillary:g} x the capillary limit"
            if a.capillary
            else f"{a.max_dt or a.write_every:g}"
        )
        + f", fields every {a.write_every:g}.\n\n"
    )
    md = markdown(results, head)
    (a.out / f"results{tag}.md").write_text(md)
    print()
    print(md)


if __name__ == "__main__":
    main()
