"""Whole-process time of Rayleigh–Taylor runs and where it goes.

Runs ``pfem2x run rayleigh-taylor`` (or ``--scene``) as a separate process a
few times per configuration and reports the medians of the whole-process wall
time (from the process start to its exit, as a user waits for it) and its
split, from ``summary.json``:

- ``startup``: process start to the first step (imports, particle-kernel cache
  load, mesh, forms, seeding, initial pressure, outputs at t = 0);
- ``particles``, ``assembly``, ``solve``, ``diagnostics``, ``output``: the
  solver's and the runner's timers over the steps (their start-up share,
  ``timings_startup``, taken off);
- ``other``: the rest (time control, guards, summary, interpreter exit).

Configurations (``--configs``; the ``-noout`` ones switch off fields,
particles and PNG, keeping the diagnostics CSV)::

    small, small-noout        the scene's small variant (16 x 64, Courant 1)
    50x200, 50x200-noout      mesh.cells = [50, 200] at the scene's Courant 8
    100x400, 100x400-noout    the scene itself (the paper's resolution)

Usage::

    python benchmarks/rt_profile.py --configs small 50x200-noout --repeat 3 \\
        --json rt_profile.json --md rt_profile.md
    python benchmarks/rt_profile.py --configs 50x200-noout --np 2   # mpirun -n 2

The load of the machine (``/proc/loadavg``) is recorded with every run:
timings taken while other processes share the cores are not comparable.
Speed targets live here and in docs/BENCHMARKS.md, never in timed tests.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

NO_OUTPUT = [
    "output.every=0",
    "output.fields=false",
    "output.particles=false",
    "output.png=false",
]
CONFIGS: dict[str, tuple[list[str], list[str]]] = {
    # name: (extra arguments, --set overrides)
    "small": (["--variant", "small"], []),
    "small-noout": (["--variant", "small"], NO_OUTPUT),
    "50x200": ([], ["mesh.cells=[50,200]"]),
    "50x200-noout": ([], ["mesh.cells=[50,200]", *NO_OUTPUT]),
    "100x400": ([], []),
    "100x400-noout": ([], NO_OUTPUT),
}
PARTS = ("startup", "particles", "assembly", "solve", "diagnostics", "output", "other")


def loadavg() -> float:
    """The one-minute load average (``nan`` where unknown)."""
    try:
        return float(Path("/proc/loadavg").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def run_once(
    python: str, scene: str, config: str, extra_set: list[str], nproc: int, out: Path
) -> dict[str, Any]:
    """One whole-process run: wall, CPU (all processes) and the split of ``summary.json``."""
    args, sets = CONFIGS[config]
    cmd = [python, "-m", "pfem2x", "run", scene, *args]
    for s in [*sets, *extra_set]:
        cmd += ["--set", s]
    cmd += ["--out", str(out), "--quiet", "--overwrite"]
    if nproc > 1:
        cmd = ["mpirun", "--allow-run-as-root", "--oversubscribe", "-n", str(nproc), *cmd]
    load = loadavg()
    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({res.returncode}):\n{res.stderr[-2000:]}")
    s = json.loads((out / "summary.json").read_text())
    tim, tim0 = s.get("timings", {}), s.get("timings_startup", {})
    split = {"startup": float(s["startup_seconds"])}
    for k in PARTS[1:-1]:
        split[k] = float(tim.get(k, 0.0)) - float(tim0.get(k, 0.0))
    split["other"] = wall - sum(split.values())
    return {
        "wall": wall,
        "cpu": (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime),
        "load": load,
        "steps": s["steps"],
        "cells": s["cells"],
        "compile_seconds": s.get("compile_seconds", 0.0),
        "operators": s.get("operators", {}),
        "split": split,
        "metrics": s.get("metrics", {}),
    }


def median_row(config: str, runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians of the runs of one configuration."""
    med = statistics.median
    return {
        "config": config,
        "runs": len(runs),
        "cells": runs[0]["cells"],
        "steps": runs[0]["steps"],
        "wall": med(r["wall"] for r in runs),
        "cpu": med(r["cpu"] for r in runs),
        "load": med(r["load"] for r in runs),
        "split": {k: med(r["split"][k] for r in runs) for k in PARTS},
    }


def markdown(rows: list[dict[str, Any]], nproc: int) -> str:
    """The table of the medians (seconds)."""
    head = ["config", "ranks", "cells", "steps", "wall", "CPU", *PARTS, "load"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        sp = r["split"]
        cells = [
            r["config"],
            str(nproc),
            str(r["cells"]),
            str(r["steps"]),
            f"{r['wall']:.2f}",
            f"{r['cpu']:.2f}",
            *(f"{sp[k]:.2f}" for k in PARTS),
            f"{r['load']:.1f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", default=["small", "small-noout"], choices=CONFIGS)
    ap.add_argument("--scene", default="rayleigh-taylor")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--np", type=int, default=1, help="MPI ranks (mpirun)")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--json", type=Path, help="write every run and the medians here")
    ap.add_argument("--md", type=Path, help="write the markdown table here")
    args = ap.parse_args(argv)
    rows, everything = [], {}
    tmp = Path(tempfile.mkdtemp(prefix="rt_profile_"))
    try:
        for config in args.configs:
            runs = []
            for i in range(args.repeat):
                r = run_once(args.python, args.scene, config, args.set, args.np, tmp / "run")
                runs.append(r)
                print(
                    f"{config} #{i + 1}: wall {r['wall']:.2f} s, CPU {r['cpu']:.2f} s, "
                    f"load {r['load']:.1f}",
                    file=sys.stderr,
                )
            everything[config] = runs
            rows.append(median_row(config, runs))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    table = markdown(rows, args.np)
    print(table)
    if args.md:
        args.md.write_text(table)
    if args.json:
        doc = {"np": args.np, "scene": args.scene, "set": args.set, "medians": rows}
        doc["runs"] = everything
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main())
