"""Rayleigh-Taylor: pfem2x (PFEM-2) against OpenFOAM interFoam, accuracy against time.

Usage::

    python benchmarks/peer_interfoam.py [--quick | --full] [--skip-openfoam]
        [--json FILE] [--md FILE] [--plot FILE] [--repeats N] [--work DIR]

Both codes solve the same problem (scene ``rayleigh-taylor``: [-0.5, 0.5] x [-2, 2],
rho 3 over 1, mu = 1e-3, g = 1, slip walls, interface y = 0.1 cos(2 pi x)) to Tryggvason
time tau = t sqrt(A g / d) = 2.5 (t = 3.5355). interFoam (OpenFOAM v1912, ``apt-get
install openfoam``) cases are written by ``benchmarks/interfoam_case.py`` with NX x NY
hexahedra and the damBreak tutorial numerics; pfem2x runs with
``--set mesh.cells=[NX,NY]`` (NX x NY squares split in 2 triangles) in its default
PFEM-2 lagrangian frame, fixed dt from ``time.courant`` and ``flow.velocity_scale``.

Error: the tip positions (spike = lowest, bubble = highest point of the interface) are
interpolated linearly in time at tau = 1, 1.5, 2, 2.5 and compared with the reference
interFoam 100 x 400, dt = 0.001 (``docs/data/rt-reference/interfoam/tips_all.csv``, columns
``r100_dt0.001:spike/bubble`` against ``tT``). ``err`` = max over those four tau and both
tips of |y - y_ref|; ``err2`` = the same up to tau = 2 only. ``err2 axis``: up to tau = 2
against interFoam 200 x 800, dt = 0.001, each tip where it lies on its axis (the spike of
the flipped run ``s200_dt0.001_signm``, the bubble of ``r200_dt0.001``: the reference of
the metric ``tip_error_axis_tau2``; interFoam's wall spike lags its axis spike, docs/RESULTS.md).

Time: pfem2x = the whole ``pfem2x run`` process (start-up, JIT, mesh, stepping; wall
clock and CPU of the child processes from ``getrusage``), its ``summary.json`` split
(``timings``: particles / assembly / solve, ``step_wall_median``). interFoam = its own
``ClockTime`` (wall) / ``ExecutionTime`` (CPU, rank 0) at t = 3.5355 read from
log.interFoam (the case runs on to the first output time after it; blockMesh and
decomposePar are not counted). Every run records /proc/loadavg before and after.

Modes (runs are sequential; threads pinned to 1 per process):

* ``--quick``: 50 x 200 only; interFoam maxCo 0.5, pfem2x Courant 8, each on 1 and
  2 ranks (about 2 minutes on an idle 2-core machine).
* default: 50 x 200; interFoam maxCo 0.5 and dt 0.01, 0.005, 0.0025; pfem2x Courant 2,
  4, 8 (medians of ``--repeats`` runs when a run takes < 60 s); 2 ranks for interFoam
  maxCo 0.5 and pfem2x Courant 8.
* ``--full``: the default plus 100 x 400: interFoam maxCo 0.5, dt 0.02 (stability
  probe), 0.01, 0.005, 0.0025 and maxCo 0.5 on 2 ranks; pfem2x Courant 2, 4, 8 on 1 and
  2 ranks (35-45 minutes on an idle machine).
* ``--skip-openfoam [GRID ...]``: no interFoam runs (on all grids, or on the grids
  given, e.g. ``--skip-openfoam 100x400``); its tips and timings are taken from the stored
  runs in ``docs/data/rt-reference/interfoam/runs.csv`` (time to tau = 2.5 = stored time per
  unit t x 3.5355), and are labelled ``stored``.

pfem2x writes only ``summary.json`` and ``diagnostics.csv`` unless ``--outputs scene``
(the scene's fields, particles and interfaces every tau = 0.25 and six PNG snapshots,
the case of the speed targets).

Subsets: ``--grids 100x400 --courants 8 --of-steps co0.5 dt0.0025`` (``--of-steps none``:
no interFoam runs). ``--pfem2x-set KEY=VALUE`` (repeatable) passes a further ``--set`` to every
pfem2x run. Every run is stopped after ``--tlim`` s; a 2-rank pfem2x run after
3 x its serial wall + 60 s.

Writes ``--json`` (all runs and the derived figures), ``--md`` (markdown tables for
docs/BENCHMARKS.md) and ``--plot`` (error against time, PNG); ``--from-json FILE``
re-derives tables and plot from a saved ``--json`` without running anything.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import re
import resource
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STORED_DIR = ROOT / "docs" / "data" / "rt-reference" / "interfoam"
sys.path.insert(0, str(Path(__file__).resolve().parent))
import interfoam_case  # noqa: E402  (benchmarks/interfoam_case.py)

TAU_END = 2.5
SQRT_A = math.sqrt(0.5)  # tau = t * sqrt(A g / d), A = 0.5, g = d = 1
T_END = TAU_END / SQRT_A  # 3.5355339
TAUS = (1.0, 1.5, 2.0, 2.5)
TAUS2 = (1.0, 1.5, 2.0)
REF_CASE = "r100_dt0.001"
#: the axis reference: (case folder, tip) of the stored 200 x 800 runs
AXIS_REF = {"spike": "s200_dt0.001_signm", "bubble": "r200_dt0.001"}
SHORT_RUN = 60.0  # seconds: repeat runs shorter than this and take the median
ONE_THREAD = {
    k: "1"
    for k in (
        "OMP_NUM_THREADS",
        "OPENBLAS_NUM_THREADS",
        "MKL_NUM_THREADS",
        "NUMBA_NUM_THREADS",
        "NUMEXPR_NUM_THREADS",
    )
}

Tips = dict[str, list[float]]  # {"spike": [y at TAUS], "bubble": [...]}
#: the errors the speed ratios are taken at (``derive``)
ERRORS = ("err", "err2", "err2_axis")


# --------------------------------------------------------------------------- helpers
def loadavg() -> list[float]:
    return [float(v) for v in Path("/proc/loadavg").read_text().split()[:3]]


def reference(stored: Path) -> Tips:
    """Reference tips at TAUS from the stored interFoam 100 x 400, dt 0.001 history."""
    with open(stored / "tips_all.csv") as f:
        rows = list(csv.DictReader(f))
    tt = np.array([float(r["tT"]) for r in rows])
    out: Tips = {}
    for k in ("spike", "bubble"):
        y = np.array([float(r[f"{REF_CASE}:{k}"]) for r in rows])
        out[k] = [float(np.interp(t, tt, y)) for t in TAUS]
    return out


def axis_reference(stored: Path) -> Tips:
    """Axis reference tips at TAUS: the spike and the bubble of :data:`AXIS_REF`."""
    out: Tips = {}
    for k, case in AXIS_REF.items():
        with open(stored / case / "tips.csv") as f:
            rows = list(csv.DictReader(f))
        tau = np.array([float(r["tau"]) for r in rows])
        y = np.array([float(r[f"y_{k}"]) for r in rows])
        out[k] = [float(np.interp(t, tau, y)) for t in TAUS]
    return out


def tips_at(tau: np.ndarray, spike: np.ndarray, bubble: np.ndarray) -> Tips:
    def one(y: np.ndarray) -> list[float]:
        return [
            float(np.interp(t, tau, y)) if tau[0] <= t <= tau[-1] + 1e-6 else math.nan for t in TAUS
        ]

    return {"spike": one(spike), "bubble": one(bubble)}


def errors(tips: Tips, ref: Tips) -> tuple[float, float]:
    """(err, err2): max |dy| of both tips over TAUS, and over TAUS2."""
    d = [[abs(tips[k][i] - ref[k][i]) for k in ("spike", "bubble")] for i in range(len(TAUS))]
    e = [max(x) for x in d]
    if any(math.isnan(v) for v in e):
        return math.nan, math.nan
    return max(e), max(e[: len(TAUS2)])


def cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_timed(cmd: list[str], log: Path, timeout: float | None = None) -> dict[str, Any]:
    """Run a command (1 thread per process), return wall, child CPU and load average.

    After ``timeout`` seconds the command's process group is terminated (rc -15).
    """
    env = dict(os.environ, **ONE_THREAD)
    env.pop("CI", None)
    load0, c0, w0 = loadavg(), cpu_children(), time.perf_counter()
    with open(log, "w") as f:
        p = subprocess.Popen(
            cmd, stdout=f, stderr=subprocess.STDOUT, env=env, start_new_session=True
        )
        timed_out = False
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            timed_out = True
            os.killpg(p.pid, signal.SIGTERM)
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
            f.write(f"\n[peer_interfoam] stopped after {timeout:g} s\n")
    wall, cpu = time.perf_counter() - w0, cpu_children() - c0
    return {
        "rc": p.returncode,
        "timed_out": timed_out,
        "wall": wall,
        "cpu": cpu,
        "load_before": load0,
        "load_after": loadavg(),
    }


def machine() -> dict[str, Any]:
    model = ""
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            model = line.split(":", 1)[1].strip()
            break
    info: dict[str, Any] = {
        "date": time.strftime("%Y-%m-%d %H:%M %Z"),
        "host": platform.node(),
        "cpu": model,
        "nproc": os.cpu_count(),
        "python": platform.python_version(),
        "load_start": loadavg(),
    }
    try:
        from pfem2x.compat import dolfinx

        info["dolfinx"] = dolfinx.__version__
    except Exception:  # noqa: BLE001 - informative only
        pass
    return info


# --------------------------------------------------------------------------- pfem2x
def run_pfem2x(
    nx: int,
    ny: int,
    courant: float,
    np_: int,
    work: Path,
    rep: int,
    tlim: float,
    extra: list[str] | None = None,
    outputs: str = "off",
) -> dict[str, Any]:
    """One ``pfem2x run`` of the scene; ``extra`` are further ``KEY=VALUE`` settings.

    ``outputs``: ``"off"`` (only ``summary.json`` and ``diagnostics.csv``) or ``"scene"``
    (the scene's fields, particles, interfaces and PNG snapshots as well).
    """
    name = f"pf_{nx}x{ny}_c{courant:g}_np{np_}_r{rep}"
    out = work / name
    off = [
        "--set", "output.every=0",
        "--set", "output.fields=false",
        "--set", "output.particles=false",
        "--set", "output.png=false",
    ]  # fmt: skip
    cmd = [
        sys.executable, "-m", "pfem2x", "run", "rayleigh-taylor",
        "--set", f"mesh.cells=[{nx},{ny}]",
        "--set", f"time.courant={courant:g}",
        *(off if outputs == "off" else []),
        "--out", str(out), "--overwrite", "--quiet",
    ]  # fmt: skip
    for kv in extra or []:
        cmd += ["--set", kv]
    if np_ > 1:
        root = ["--allow-run-as-root"] if os.geteuid() == 0 else []
        cmd = ["mpirun", *root, "-n", str(np_), *cmd]
    work.mkdir(parents=True, exist_ok=True)
    t = run_timed(cmd, work / f"{name}.log", tlim)
    rec: dict[str, Any] = {
        "code": "pfem2x", "grid": f"{nx}x{ny}", "cells": [nx, ny], "np": np_, "outputs": outputs,
        "config": f"Courant {courant:g}" + (", outputs" if outputs == "scene" else ""),
        "courant": courant, "source": "measured",
        "wall": t["wall"], "cpu": t["cpu"], "load_before": t["load_before"],
        "load_after": t["load_after"], "rc": t["rc"],
    }  # fmt: skip
    sfile = out / "summary.json"
    if t["rc"] != 0 or not sfile.exists():
        rec["status"] = (
            f"timed out after {tlim:g} s" if t["timed_out"] else "failed"
        ) + f" (rc {t['rc']}, see {name}.log)"
        return rec
    s = json.loads(sfile.read_text())
    m = s["metrics"]
    tf, tr = np.array(m["tip_falling"]), np.array(m["tip_rising"])
    rec.update(
        status=s["status"],
        steps=s["steps"],
        dt=s["dt"],
        courant_max=s["courant_max"],
        run_wall=s["wall_seconds"],
        run_cpu=s["cpu_seconds"],
        setup=s["setup_seconds"],
        step_wall_median=s["step_wall_median"],
        step_wall_mean=s["wall_seconds"] / max(s["steps"], 1),
        timings=s["timings"],
        tips=tips_at(tf[:, 0], tf[:, 1], tr[:, 1]),
    )
    return rec


# --------------------------------------------------------------------------- interFoam
_TIME = re.compile(r"^Time = (\S+)\s*$", re.M)
_EXEC = re.compile(r"^ExecutionTime = (\S+) s\s+ClockTime = (\S+) s", re.M)
_CO = re.compile(r"^Courant Number mean: \S+ max: (\S+)", re.M)


def parse_foam_log(log: str) -> dict[str, Any]:
    """Steps, CPU (ExecutionTime) and wall (ClockTime) up to t = T_END, max Courant."""
    times = [(m.start(), float(m.group(1))) for m in _TIME.finditer(log)]
    execs = [(m.start(), float(m.group(1)), float(m.group(2))) for m in _EXEC.finditer(log)]
    cos = [(m.start(), float(m.group(1))) for m in _CO.finditer(log)]
    # pair each "Time =" with the next ExecutionTime line
    steps: list[tuple[float, float, float]] = []
    j = 0
    for pos, t in times:
        while j < len(execs) and execs[j][0] < pos:
            j += 1
        if j < len(execs):
            steps.append((t, execs[j][1], execs[j][2]))
    if not steps:
        return {}
    ts = np.array([s[0] for s in steps])
    k = int(np.searchsorted(ts, T_END - 1e-9))
    if k >= len(steps):
        return {"t_last": float(ts[-1])}
    t0, c0, w0 = (0.0, 0.0, 0.0) if k == 0 else steps[k - 1]
    t1, c1, w1 = steps[k]
    f = (T_END - t0) / (t1 - t0)
    end_pos = times[k][0]
    return {
        "t_last": float(ts[-1]),
        "steps": k + f,
        "cpu_to_end": c0 + f * (c1 - c0),
        "wall_to_end": w0 + f * (w1 - w0),
        "courant_max": max((c for p, c in cos if p < end_pos), default=math.nan),
    }


def read_foam_tips(case: Path) -> Tips | None:
    """Tips at TAUS of a finished case (writes ``case/tips.csv``)."""
    rows = interfoam_case.write_tips(case)
    if len(rows) < 2:
        return None
    return tips_at(rows[:, 1], rows[:, 2], rows[:, 3])


def run_interfoam(nx: int, ny: int, step: str, np_: int, work: Path, tlim: int) -> dict[str, Any]:
    """One interFoam case; ``step`` is ``co<maxCo>`` (adaptive) or ``dt<deltaT>``."""
    name = f"of_{nx}x{ny}_{step}_np{np_}"
    case = work / name
    if case.exists():
        shutil.rmtree(case)
    work.mkdir(parents=True, exist_ok=True)
    opt = ["--max-co", step[2:]] if step.startswith("co") else ["--dt", step[2:]]
    subprocess.run(
        [sys.executable, str(Path(interfoam_case.__file__)), "make", str(case),
         "--nx", str(nx), "--ny", str(ny), *opt, "--nproc", str(max(np_, 2))],
        check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    run = [sys.executable, str(Path(interfoam_case.__file__)), "run", str(case)]
    run += ["--np", str(np_), "--tlim", str(tlim)]
    t = run_timed(run, work / f"{name}.log", tlim + 300)
    label = f"maxCo {step[2:]}" if step.startswith("co") else f"dt {step[2:]}"
    rec: dict[str, Any] = {
        "code": "interFoam", "grid": f"{nx}x{ny}", "cells": [nx, ny], "np": np_,
        "config": label, "source": "measured", "process_wall": t["wall"],
        "process_cpu": t["cpu"], "load_before": t["load_before"],
        "load_after": t["load_after"], "rc": t["rc"],
    }  # fmt: skip
    logf = case / "log.interFoam"
    info = parse_foam_log(logf.read_text(errors="replace")) if logf.exists() else {}
    if "cpu_to_end" not in info:
        rec["status"] = f"unstable/failed (reached t = {info.get('t_last', 0):.3g})"
        return rec
    tips = read_foam_tips(case)
    rec.update(
        status="ok",
        steps=info["steps"],
        courant_max=info["courant_max"],
        wall=info["wall_to_end"],
        cpu=info["cpu_to_end"],
        step_wall_mean=info["wall_to_end"] / info["steps"],
        tips=tips,
    )
    if tips is None or any(math.isnan(v) for v in tips["spike"] + tips["bubble"]):
        rec["status"] = "no interface / unstable"
    # keep the logs and tips.csv, drop the bulky time directories
    for d in case.iterdir():
        if d.is_dir() and (re.fullmatch(r"[0-9.e-]+", d.name) or d.name.startswith("proc")):
            if d.name != "0":
                shutil.rmtree(d)
    return rec


# stored interFoam runs: (grid, config label, np) -> case name in runs.csv
STORED = {
    ("50x200", "maxCo 0.5", 1): "t050_co0.5",
    ("50x200", "maxCo 0.5", 2): "n050_co0.5_np2",
    ("50x200", "dt 0.01", 1): "r050_dt0.01",
    ("50x200", "dt 0.005", 1): "r050_dt0.005",
    ("50x200", "dt 0.0025", 1): "r050_dt0.0025",
    ("50x200", "dt 0.001", 1): "r050_dt0.001",
    ("100x400", "maxCo 0.5", 1): "t100_co0.5",
    ("100x400", "maxCo 0.5", 2): "r100_co0.5_np2",
    ("100x400", "dt 0.01", 1): "r100_dt0.01",
    ("100x400", "dt 0.005", 1): "r100_dt0.005",
    ("100x400", "dt 0.0025", 1): "r100_dt0.0025",
    ("100x400", "dt 0.001", 1): "r100_dt0.001",
}


def stored_interfoam(stored: Path, grids: list[str]) -> list[dict[str, Any]]:
    with open(stored / "runs.csv") as f:
        rows = {r["case"]: r for r in csv.DictReader(f)}
    out = []
    for (grid, label, np_), name in STORED.items():
        if grid not in grids or name not in rows:
            continue
        r = rows[name]
        key = {1.0: "1.0", 1.5: "1.5", 2.0: "2.0", 2.5: "2.5"}
        tips = {
            "spike": [float(r[f"s_tT{key[t]}"]) for t in TAUS],
            "bubble": [float(r[f"b_tT{key[t]}"]) for t in TAUS],
        }
        tl = float(r["tlast"])
        nx, ny = (int(v) for v in grid.split("x"))
        out.append(
            {
                "code": "interFoam", "grid": grid, "cells": [nx, ny], "np": np_,
                "config": label, "source": f"stored ({name})", "status": r["status"],
                "steps": float(r["steps"]) * T_END / tl,
                "wall": float(r["wall"]) * T_END / tl,
                "cpu": float(r["cpu"]) * T_END / tl,
                "step_wall_mean": float(r["wall"]) / float(r["steps"]),
                "courant_max": float(r["maxCo"]), "tips": tips,
                "reference": name == REF_CASE,
            }
        )  # fmt: skip
    return out


# --------------------------------------------------------------------------- analysis
def median_runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Median record of repeated runs (by process wall); keeps every repeat's times."""
    ok = [r for r in runs if r.get("status") == "ok"] or runs
    ok = sorted(ok, key=lambda r: r["wall"])
    rec = dict(ok[len(ok) // 2])
    rec["repeats"] = len(ok)
    rec["failed_repeats"] = [r["status"] for r in runs if r.get("status") != "ok"]
    rec["walls"] = [r["wall"] for r in ok]
    rec["cpus"] = [r["cpu"] for r in ok]
    rec["wall"] = statistics.median(rec["walls"])
    rec["cpu"] = statistics.median(rec["cpus"])
    return rec


def derive(runs: list[dict[str, Any]], ref: Tips, use: str, axis: Tips) -> dict[str, Any]:
    """Errors, speed ratios at equal or better error, cost growth and 2-rank speed-ups."""
    for r in runs:
        if r.get("tips"):
            r["err"], r["err2"] = errors(r["tips"], ref)
            r["err2_axis"] = errors(r["tips"], axis)[1]
        else:
            r["err"] = r["err2"] = r["err2_axis"] = math.nan
    good = [r for r in runs if r.get("status") == "ok" and not math.isnan(r["err"])]
    ratios = []
    best = []
    pf1 = [r for r in good if r["code"] == "pfem2x" and r["np"] == 1]
    of1 = [r for r in good if r["code"] == "interFoam" and r["np"] == 1 and not r.get("reference")]
    for ekey in ERRORS:
        # any grid: for each pfem2x run, the cheapest interFoam run on either grid as accurate
        for p in pf1:
            ok = [f for f in of1 if f[ekey] <= p[ekey]]
            if ok:
                f = min(ok, key=lambda x: x[use])
                best.append(
                    {
                        "error": ekey, "interfoam": f"{f['grid']} {f['config']}",
                        "interfoam_source": f["source"], "interfoam_err": f[ekey],
                        "interfoam_time": f[use], "pfem2x": f"{p['grid']} {p['config']}",
                        "pfem2x_err": p[ekey], "pfem2x_time": p[use],
                        "ratio": f[use] / p[use],
                    }
                )  # fmt: skip
    for p in pf1:
        cands = [f for f in of1 if f["grid"] == p["grid"]]
        if not cands:
            continue
        for ekey in ERRORS:
            better = [f for f in cands if f[ekey] <= p[ekey]]
            if better:
                f = min(better, key=lambda x: x[use])
                bound = "="
            else:  # no interFoam run this accurate: ratio to the most accurate is a bound
                f = min(cands, key=lambda x: x[ekey])
                bound = ">"
            ratios.append(
                {
                    "grid": p["grid"], "pfem2x": p["config"], "error": ekey,
                    "pfem2x_err": p[ekey], "pfem2x_time": p[use],
                    "interfoam": f["config"], "interfoam_source": f["source"],
                    "interfoam_err": f[ekey], "interfoam_time": f[use],
                    "ratio": f[use] / p[use], "bound": bound,
                }
            )  # fmt: skip
    growth = []
    for cfg in sorted({r["config"] for r in good if r["code"] == "pfem2x"}):
        by = {
            r["grid"]: r
            for r in good
            if r["code"] == "pfem2x" and r["config"] == cfg and r["np"] == 1
        }
        if "50x200" in by and "100x400" in by:
            a, b = by["50x200"], by["100x400"]
            growth.append(
                {
                    "config": cfg,
                    "step_50x200": a["step_wall_median"],
                    "step_100x400": b["step_wall_median"],
                    "ratio": b["step_wall_median"] / a["step_wall_median"],
                }
            )
    speedup = []
    for code in ("pfem2x", "interFoam"):
        for grid in ("50x200", "100x400"):
            for cfg in sorted({r["config"] for r in good}):
                one = [
                    r for r in good
                    if (r["code"], r["grid"], r["config"], r["np"]) == (code, grid, cfg, 1)
                ]  # fmt: skip
                two = [
                    r for r in good
                    if (r["code"], r["grid"], r["config"], r["np"]) == (code, grid, cfg, 2)
                ]  # fmt: skip
                if one and two:
                    speedup.append(
                        {
                            "code": code, "grid": grid, "config": cfg,
                            "wall_np1": one[0]["wall"], "wall_np2": two[0]["wall"],
                            "speedup": one[0]["wall"] / two[0]["wall"],
                            "source": two[0]["source"],
                        }
                    )  # fmt: skip
    return {"ratios": ratios, "best": best, "growth": growth, "speedup": speedup}


# --------------------------------------------------------------------------- output
def fmt(v: Any, nd: int = 3) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def tables(res: dict[str, Any]) -> str:
    runs, d, use = res["runs"], res["derived"], res["time_measure"]
    lines = [
        "| code | grid | ranks | step | source | steps | max Co | wall s | CPU s | s/step "
        "| particles / assembly / solve s | err | err2 | err2 axis | tips τ=2.5 spike/bubble "
        "| load |",
        "|---|---|---:|---|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---|---|",
    ]
    for r in runs:
        tim = r.get("timings")
        split = (
            " / ".join(fmt(tim.get(k, 0.0), 1) for k in ("particles", "assembly", "solve"))
            if tim
            else ""
        )
        tips = r.get("tips")
        tip = f"{tips['spike'][-1]:.3f} / {tips['bubble'][-1]:.3f}" if tips else "–"
        load = f"{r['load_before'][0]:.2f}→{r['load_after'][0]:.2f}" if "load_before" in r else ""
        wall = fmt(r.get("wall"), 1)
        if r.get("repeats", 1) > 1:
            wall += f" (med. of {r['repeats']})"
        step = r.get("step_wall_median", r.get("step_wall_mean"))
        lines.append(
            f"| {r['code']} | {r['grid']} | {r['np']} | {r['config']} | {r['source']} "
            f"| {fmt(r.get('steps'), 0)} | {fmt(r.get('courant_max'), 2)} | {wall} "
            f"| {fmt(r.get('cpu'), 1)} | {fmt(step, 3)} | {split} | {fmt(r.get('err'))} "
            f"| {fmt(r.get('err2'))} | {fmt(r.get('err2_axis'))} | {tip} | {load} |"
        )
        if r.get("status") != "ok":
            lines[-1] += f" {r.get('status')}"
    out = ["\n".join(lines), ""]
    if d["ratios"]:
        out.append(
            f"Speed ratio on one core ({use} time to τ = 2.5) = interFoam time / pfem2x time, "
            "against the cheapest interFoam run on the same grid with equal or smaller error "
            "(`>`: no interFoam run was as accurate; the ratio is to the most accurate one):\n"
        )
        out.append(
            "| grid | pfem2x | error | pfem2x err | time s | interFoam | err | time s | ratio |"
        )
        out.append("|---|---|---|---:|---:|---|---:|---:|---:|")
        for q in d["ratios"]:
            out.append(
                f"| {q['grid']} | {q['pfem2x']} | {q['error']} | {q['pfem2x_err']:.3f} "
                f"| {q['pfem2x_time']:.1f} | {q['interfoam']} ({q['interfoam_source']}) "
                f"| {q['interfoam_err']:.3f} | {q['interfoam_time']:.1f} "
                f"| {'≥ ' if q['bound'] == '>' else ''}{q['ratio']:.1f} |"
            )
        out.append("")
    if d.get("best"):
        out.append(
            f"Any grid ({use} time to τ = 2.5, one core): for each pfem2x run, the cheapest "
            "interFoam run on either grid with equal or smaller error (each code may reach "
            "an accuracy on the coarser mesh):\n"
        )
        out.append("| error | pfem2x | err | time s | interFoam | err | time s | ratio |")
        out.append("|---|---|---:|---:|---|---:|---:|---:|")
        for q in sorted(d["best"], key=lambda q: (q["error"], q["pfem2x_err"])):
            out.append(
                f"| {q['error']} | {q['pfem2x']} | {q['pfem2x_err']:.3f} "
                f"| {q['pfem2x_time']:.1f} | {q['interfoam']} ({q['interfoam_source']}) "
                f"| {q['interfoam_err']:.3f} | {q['interfoam_time']:.1f} | {q['ratio']:.1f} |"
            )
        out.append("")
    if d["growth"]:
        out.append("pfem2x cost growth per step, 50×200 → 100×400 (4× cells):\n")
        out.append("| pfem2x | s/step 50×200 | s/step 100×400 | ratio |")
        out.append("|---|---:|---:|---:|")
        for g in d["growth"]:
            out.append(
                f"| {g['config']} | {g['step_50x200']:.3f} | {g['step_100x400']:.3f} "
                f"| {g['ratio']:.2f} |"
            )
        out.append("")
    if d["speedup"]:
        out.append("2-rank speed-up (wall, 1 rank / 2 ranks):\n")
        out.append("| code | grid | step | wall 1 rank s | wall 2 ranks s | speed-up | source |")
        out.append("|---|---|---|---:|---:|---:|---|")
        for s in d["speedup"]:
            out.append(
                f"| {s['code']} | {s['grid']} | {s['config']} | {s['wall_np1']:.1f} "
                f"| {s['wall_np2']:.1f} | {s['speedup']:.2f} | {s['source']} |"
            )
        out.append("")
    return "\n".join(out)


def plot(res: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    use = res["time_measure"]
    fig, axes = plt.subplots(1, 2, figsize=(9.0, 3.8), sharey=True)
    style = {
        ("pfem2x", "50x200"): ("o", "tab:blue"),
        ("pfem2x", "100x400"): ("s", "tab:blue"),
        ("interFoam", "50x200"): ("o", "tab:red"),
        ("interFoam", "100x400"): ("s", "tab:red"),
    }
    for ax, ekey, title in zip(axes, ("err", "err2"), ("τ ≤ 2.5", "τ ≤ 2"), strict=True):
        for (code, grid), (mk, col) in style.items():
            rs = [
                r
                for r in res["runs"]
                if r["code"] == code
                and r["grid"] == grid
                and r["np"] == 1
                and r.get("status") == "ok"
                and not math.isnan(r.get(ekey, math.nan))
                and not r.get("reference")
            ]
            if not rs:
                continue
            stored = all(r["source"].startswith("stored") for r in rs)
            rs.sort(key=lambda r: r[use])
            ax.plot(
                [r[use] for r in rs],
                [r[ekey] for r in rs],
                marker=mk,
                color=col,
                mfc="none" if stored else col,
                ls="-" if code == "pfem2x" else "--",
                label=f"{code} {grid}" + (" (stored)" if stored else ""),
            )
            for r in rs:
                lab = r["config"].replace("Courant ", "C").replace("maxCo ", "Co")
                ax.annotate(lab, (r[use], r[ekey]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")  # fmt: skip
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{use} time to τ = 2.5, one core [s]")
        ax.set_title(f"max tip error, {title}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("|Δy| vs interFoam 100×400 Δt 0.001")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"Rayleigh–Taylor, pfem2x vs interFoam ({res['machine']['date']})", fontsize=9)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------- main
def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true", help="50x200, one step size per code")
    mode.add_argument("--full", action="store_true", help="50x200 and 100x400")
    ap.add_argument(
        "--skip-openfoam",
        nargs="*",
        metavar="GRID",
        help="use the stored interFoam runs instead of running interFoam (on all grids, or "
        "on the grids given, e.g. 100x400)",
    )
    ap.add_argument("--json", type=Path, help="write all results here")
    ap.add_argument("--md", type=Path, help="write the markdown tables here")
    ap.add_argument("--plot", type=Path, help="write the error-vs-time PNG here")
    ap.add_argument("--repeats", type=int, default=3, help="runs of short pfem2x cases")
    ap.add_argument("--time", choices=["cpu", "wall"], default="cpu",
                    help="time used for the speed ratios and the plot (default cpu)")  # fmt: skip
    ap.add_argument("--work", type=Path, default=ROOT / "benchmarks/_work/peer_interfoam")
    ap.add_argument("--stored", type=Path, default=STORED_DIR,
                    help="stored interFoam runs (tips_all.csv, runs.csv)")  # fmt: skip
    ap.add_argument("--tlim", type=int, default=1500, help="time limit of one run, s")
    ap.add_argument(
        "--pfem2x-set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="a further --set for every pfem2x run, e.g. mesh.diagonal=right",
    )
    ap.add_argument(
        "--outputs",
        choices=["off", "scene"],
        default="off",
        help="pfem2x's files: off (summary and CSV only) or as the scene asks",
    )
    ap.add_argument("--grids", nargs="+", metavar="GRID", help="only these, e.g. 100x400")
    ap.add_argument("--courants", nargs="+", type=float, help="only these pfem2x Courants")
    ap.add_argument("--of-steps", nargs="+", help="only these interFoam steps, e.g. dt0.0025")
    ap.add_argument(
        "--from-json", type=Path, help="no runs: re-derive tables and plot from a saved --json"
    )
    args = ap.parse_args()
    if args.from_json:
        res = json.loads(args.from_json.read_text())
        res["time_measure"] = args.time
        axis = res["reference"].get("axis_tips") or axis_reference(args.stored)
        res["derived"] = derive(res["runs"], res["reference"]["tips"], args.time, axis)
        report(res, args)
        return

    if args.quick:
        plan_pf = {"50x200": [(8.0, 1), (8.0, 2)]}
        plan_of = {"50x200": [("co0.5", 1), ("co0.5", 2)]}
        repeats = 1
    else:
        cs = [2.0, 4.0, 8.0]
        plan_pf = {"50x200": [(c, 1) for c in cs] + [(8.0, 2)]}
        plan_of = {"50x200": [("co0.5", 1), ("dt0.01", 1), ("dt0.005", 1), ("dt0.0025", 1),
                              ("co0.5", 2)]}  # fmt: skip
        repeats = args.repeats
        if args.full:
            plan_pf["100x400"] = [(c, 1) for c in cs] + [(c, 2) for c in cs]
            plan_of["100x400"] = [("co0.5", 1), ("dt0.02", 1), ("dt0.01", 1), ("dt0.005", 1),
                                  ("dt0.0025", 1), ("co0.5", 2)]  # fmt: skip
    if args.grids:
        plan_pf = {g: v for g, v in plan_pf.items() if g in args.grids}
    if args.courants:
        plan_pf = {g: [(c, n) for c, n in v if c in args.courants] for g, v in plan_pf.items()}
    if args.of_steps:
        plan_of = {g: [(s, n) for s, n in v if s in args.of_steps] for g, v in plan_of.items()}
    grids = list(plan_pf)
    skip = set() if args.skip_openfoam is None else set(args.skip_openfoam or grids)
    if set(grids) - skip and not Path("/usr/bin/interFoam").exists():
        print("error: interFoam not found: apt-get install -y openfoam, or use --skip-openfoam",
              file=sys.stderr)  # fmt: skip
        raise SystemExit(2)

    ref = reference(args.stored)
    res: dict[str, Any] = {
        "machine": machine(),
        "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        "reference": {
            "case": REF_CASE,
            "taus": TAUS,
            "tips": ref,
            "axis_cases": AXIS_REF,
            "axis_tips": axis_reference(args.stored),
        },
        "time_measure": args.time,
        "runs": [],
    }
    runs: list[dict[str, Any]] = res["runs"]

    def say(r: dict[str, Any]) -> None:
        print(
            f"  {r['code']:9s} {r['grid']:7s} np{r['np']} {r['config']:12s} "
            f"{r.get('status', '?'):8s} wall {fmt(r.get('wall'), 1):>7s} s  "
            f"cpu {fmt(r.get('cpu'), 1):>7s} s  load {r.get('load_before', ['-'])[0]}"
            f"->{r.get('load_after', ['-'])[0]}",
            flush=True,
        )

    for grid in grids:
        nx, ny = (int(v) for v in grid.split("x"))
        for c, np_ in plan_pf[grid]:
            # bound a 2-rank run by 3x the serial wall (a hung rank must not stall the benchmark)
            tlim = float(args.tlim)
            serial = [
                r["wall"]
                for r in runs
                if r["code"] == "pfem2x" and r["grid"] == grid and r.get("courant") == c
                and r["np"] == 1 and r.get("status") == "ok"
            ]  # fmt: skip
            if np_ > 1 and serial:
                tlim = min(tlim, 3.0 * serial[0] + 60.0)
            reps = [run_pfem2x(nx, ny, c, np_, args.work, 0, tlim, args.pfem2x_set, args.outputs)]
            say(reps[0])
            if reps[0].get("status") == "ok" and reps[0]["wall"] < SHORT_RUN and np_ == 1:
                for k in range(1, repeats):
                    reps.append(
                        run_pfem2x(
                            nx, ny, c, np_, args.work, k, tlim, args.pfem2x_set, args.outputs
                        )
                    )
                    say(reps[-1])
            runs.append(median_runs(reps) if len(reps) > 1 else reps[0])
        if grid in skip:
            continue
        for step, np_ in plan_of[grid]:
            r = run_interfoam(nx, ny, step, np_, args.work, args.tlim)
            say(r)
            runs.append(r)
    if skip:
        runs.extend(stored_interfoam(args.stored, [g for g in grids if g in skip]))
    res["machine"]["load_end"] = loadavg()
    res["derived"] = derive(runs, ref, args.time, res["reference"]["axis_tips"])
    report(res, args)


def report(res: dict[str, Any], args: argparse.Namespace) -> None:
    """Print the tables; write --md, --json and --plot."""
    md = tables(res)
    print()
    print(md)
    head = (
        f"`{res['command']}` — {res['machine']['date']}, {res['machine']['cpu']}, "
        f"nproc {res['machine']['nproc']}, load average {res['machine']['load_start']} at "
        f"start, {res['machine']['load_end']} at end.\n\n"
    )
    if args.md:
        args.md.write_text(head + md + "\n")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1, default=float) + "\n")
    if args.plot:
        plot(res, args.plot)
        print(f"plot: {args.plot} ({args.plot.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
