"""Speed of the particle layer (one process): move+locate, projection, memory.

Usage::

    python benchmarks/particles.py [--quick] [--json FILE]

Mesh: rectangle [-0.5, 0.5] x [-2, 2], 100 x 400 cells split in 2 (80,000
triangles), 8 particles per cell (640,000 particles), rigid rotation about
the origin, one step of Courant 8 (max |u| dt / h_min) in 16 RK2 sub-steps.
Reported figures are medians of 5 (``--quick``) or 7 runs, 4x as many for
the projection. ``--quick``: that size only. At 640,000 particles also the
move of the flow frame: sub-steps limited to Courant 0.5 and gradient
Courant 0.1, a 2-component P1 source integrated along the path.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI, dolfinx
from pfem2x.mesh import build_mesh
from pfem2x.particles import Cloud, advect, project, seed_cells


def _median_time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def measure_path(domain, u, per_cell: int, dt: float, repeats: int) -> dict:
    """The flow frame's move: Courant-limited sub-steps and a vector source on the path."""
    cl = Cloud(domain, {"u": (2,)})
    seed_cells(cl, per_cell, seed=1)
    f = dolfinx.fem.Function(u.function_space)
    f.interpolate(lambda x: np.stack([np.sin(x[1]), np.cos(x[0])]))
    kw = {"courant": 0.5, "gradient_courant": 0.1, "source": f, "source_field": "u"}
    advect(cl, u, dt, **kw)  # warm-up, sorted cloud
    steps = []
    t = _median_time(lambda: steps.append(advect(cl, u, dt, **kw).substeps), repeats)
    return {"substeps_per_particle": float(np.median(steps)) / cl.n, "per_s": np.median(steps) / t}


def measure(domain, u, T, per_cell: int, dt: float, repeats: int) -> dict:
    cl = Cloud(domain, {"T": ()})
    seed_cells(cl, per_cell, seed=1)
    cl["T"] = np.sin(cl.x[:, 0]) * cl.x[:, 1]
    n = cl.n
    # warm-up (JIT compile / caches) and a sorted cloud
    advect(cl, u, dt, substeps=16)
    project(cl, "T", T)
    steps = []

    def move():
        steps.append(advect(cl, u, dt, substeps=16).substeps)

    t_move = _median_time(move, repeats)
    # projection is ~50x cheaper than the move: more repeats for a stable median
    t_proj = _median_time(lambda: project(cl, "T", T, method="linear"), 4 * repeats)
    t_avg = _median_time(lambda: project(cl, "T", T, method="average"), 4 * repeats)
    return {
        "particles": n,
        "substeps": int(np.median(steps)),
        "t_move": t_move,
        "move_substeps_per_s": float(np.median(steps)) / t_move,
        "t_project": t_proj,
        "project_per_s": n / t_proj,
        "project_average_per_s": n / t_avg,
        "bytes_per_particle": cl.bytes_per_particle(),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="one size, under a minute")
    ap.add_argument("--json", help="write the headline figures to this file")
    args = ap.parse_args()
    comm = MPI.COMM_SELF
    load0 = os.getloadavg()[0]
    d = build_mesh(comm, "rectangle", [[-0.5, -2.0], [0.5, 2.0]], [100, 400])
    V = compat.function_space(d.mesh, 1, (2,))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.stack([-x[1], x[0]]))
    T = dolfinx.fem.Function(compat.function_space(d.mesh, 1))
    umax = float(np.hypot(0.5, 2.0))
    dt = 8.0 * d.min_h() / umax
    repeats = 5 if args.quick else 7
    rows = []
    base = measure(d, u, T, 8, dt, repeats)
    small = measure(d, u, T, 2, dt, repeats)
    rows += [small, base]
    if not args.quick:
        for ppc in (1, 25):  # 80,000 and 2,000,000 particles
            rows.append(measure(d, u, T, ppc, dt, repeats))
    rows.sort(key=lambda r: r["particles"])
    path = measure_path(d, u, 8, dt, repeats)
    ratio = base["t_move"] / small["t_move"]
    load = (load0, os.getloadavg()[0])
    print(
        f"particles benchmark  ({platform.processor() or platform.machine()}, 1 process, "
        f"load average {load[0]:.2f} -> {load[1]:.2f} on {os.cpu_count()} cores)"
    )
    print(f"{'particles':>10} {'substeps':>10} {'move s':>8} {'M sub/s':>8} "
          f"{'proj s':>8} {'M p/s lin':>9} {'M p/s avg':>9}")  # fmt: skip
    for r in rows:
        print(
            f"{r['particles']:>10d} {r['substeps']:>10d} {r['t_move']:>8.3f} "
            f"{r['move_substeps_per_s'] / 1e6:>8.2f} {r['t_project']:>8.3f} "
            f"{r['project_per_s'] / 1e6:>9.2f} {r['project_average_per_s'] / 1e6:>9.2f}"
        )
    print(
        f"640k, flow move (Courant 0.5, path source): {path['per_s'] / 1e6:.2f} M sub/s, "
        f"{path['substeps_per_particle']:.2f} sub-steps per particle"
    )
    print(f"linearity time(640k)/time(160k) = {ratio:.2f} (limit 4.4)")
    print(f"bytes per particle (x, cell, T) = {base['bytes_per_particle']:.0f}")
    out = {
        "move_locate_substeps_per_s": base["move_substeps_per_s"],
        "project_particles_per_s": base["project_per_s"],
        "move_path_source_substeps_per_s": float(path["per_s"]),
        "linearity_ratio_4x": ratio,
        "bytes_per_particle": base["bytes_per_particle"],
        "load_average": list(load),
    }
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)


if __name__ == "__main__":
    main()
