# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Paper Table 5.2: manufactured 1D problem on three meshes
#
# The manufactured problem of Table 5.1 (`demos/table_5_1.py`) at ω = 5 (the
# paper's H = 0.2 column repeats its ω = 5 column of Table 5.1) on a fine
# (H = 0.1, 120 cells), standard (H = 0.2, 60 cells) and coarse (H = 0.4,
# 30 cells) mesh, Δt ∈ {0.2, 0.1, 0.05, 0.01}: time average over 50 s of the
# L2 error × 100, PFEM-2 (average and linear-exact projection, 10 particles
# per cell) and Eulerian θ = ½, the paper's numbers beside ours.
#
#     python demos/table_5_2.py      # 36 runs, 4 min wall (shared 2-core machine, load ~5)
#
# Writes `table_5_2.md` / `table_5_2.csv` under `$PFEM2X_DEMO_OUT`
# (default `runs/demos/table_5_2/`); `PFEM2X_DEMO_SMALL=1` runs 5 s and a few
# entries. Runs under `mpirun -n 2` too; rank 0 prints and writes.

# %%
import csv
import os
import time
from pathlib import Path

from mpi4py import MPI

from pfem2x.runner import Simulation
from pfem2x.scene import load_scene

small = os.environ.get("PFEM2X_DEMO_SMALL") == "1"
out = Path(os.environ.get("PFEM2X_DEMO_OUT", "runs/demos")) / "table_5_2"
comm = MPI.COMM_WORLD
rank0 = comm.rank == 0

OMEGA = 5.0
DTS = [0.2, 0.05] if small else [0.2, 0.1, 0.05, 0.01]
#: mesh size H -> cells on [-6, 6]
MESHES = {0.2: 60, 0.4: 30} if small else {0.1: 120, 0.2: 60, 0.4: 30}
METHODS = {
    "lagr_average": ["method.frame=lagrangian", "method.projection=average"],
    "lagr_linear": ["method.frame=lagrangian", "method.projection=linear"],
    "eulerian": ["method.frame=eulerian", "method.theta=0.5"],
}
#: the paper's Table 5.2 (Lagrangian, Eulerian) per (H, Δt)
PAPER = {
    (0.1, 0.2): ("0.13", "≫1"),
    (0.1, 0.1): ("0.13", "≫1"),
    (0.1, 0.05): ("0.13", "3.3"),
    (0.1, 0.01): ("0.13", "0.11"),
    (0.2, 0.2): ("0.31", "≫1"),
    (0.2, 0.1): ("0.31", "≫1"),
    (0.2, 0.05): ("0.30", "3.3"),
    (0.2, 0.01): ("0.30", "0.09"),
    (0.4, 0.2): ("0.94", "≫1"),
    (0.4, 0.1): ("0.94", "≫1"),
    (0.4, 0.05): ("0.94", "3.4"),
    (0.4, 0.01): ("0.94", "0.21"),
}


def run_case(overrides: list[str], tag: str) -> dict:
    """One run of the manufactured scene; the time-averaged L2 error × 100 and the wall time."""
    scene = load_scene(
        "manufactured-1d",
        overrides + ["output.png=false", "output.fields=false", "output.csv=false"],
        variant="small" if small else None,
    )
    res = Simulation(scene, out / "runs" / tag, comm, quiet=True, overwrite=True).run()
    err = res.summary["metrics"].get("l2_error_time_avg", float("nan"))
    return {"status": res.status, "err100": 100.0 * err, "wall": res.summary["wall_seconds"]}


def fmt(r: dict) -> str:
    """A table entry: the error × 100, or the run's status if it did not finish."""
    if r["status"] != "ok":
        return r["status"]
    v = r["err100"]
    return f"{v:.2f}" if v < 10 else f"{v:.3g}"


# %%
wall0 = time.perf_counter()
results: dict[tuple[float, float, str], dict] = {}
for H, cells in MESHES.items():
    for dt in DTS:
        for name, ov in METHODS.items():
            tag = f"H{H:g}-dt{dt:g}-{name}"
            ovr = ov + [f"params.omega={OMEGA}", f"time.dt={dt}", f"mesh.cells=[{cells}]"]
            results[H, dt, name] = run_case(ovr, tag)
wall_total = time.perf_counter() - wall0

# %% [markdown]
# The table (P = paper, avg / lin = our PFEM-2 with average / linear-exact
# projection, Eul = our Eulerian θ = ½). The Courant number V Δt / H runs
# from 2.5 Δt / H to 7.5 Δt / H.

# %%
head = ["Δt"]
for H in MESHES:
    head += [f"H={H:g} Lagr P", "avg", "lin", "Eul P", "Eul"]
rows = []
for dt in DTS:
    row = [f"{dt:g}"]
    for H in MESHES:
        pl, pe = PAPER[H, dt]
        row += [
            pl,
            fmt(results[H, dt, "lagr_average"]),
            fmt(results[H, dt, "lagr_linear"]),
            pe,
            fmt(results[H, dt, "eulerian"]),
        ]
    rows.append(row)
md = "| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n"
md += "".join("| " + " | ".join(r) + " |\n" for r in rows)
t_end = 5.0 if small else 50.0
md += (
    f"\nω = {OMEGA:g}; average over the first {t_end:g} s of the L2 error × 100; 10 particles"
    f" per cell; {len(results)} runs, {wall_total:.0f} s wall on {comm.size} process(es).\n"
)
if rank0:
    print(md)
    out.mkdir(parents=True, exist_ok=True)
    (out / "table_5_2.md").write_text(md)
    with open(out / "table_5_2.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["H", "dt", "method", "status", "l2_err_x100", "paper_x100", "wall_s"])
        for (H, dt, name), r in results.items():
            paper = PAPER[H, dt][1 if name == "eulerian" else 0]
            w.writerow([H, dt, name, r["status"], f"{r['err100']:.4g}", paper, f"{r['wall']:.2f}"])
    print(f"wrote {out / 'table_5_2.md'} and {out / 'table_5_2.csv'}")

# %%
# PFEM-2: the error falls with the mesh size and hardly depends on Δt.
assert all(r["status"] == "ok" for k, r in results.items() if k[2] != "eulerian")
Hs = sorted(MESHES)
for dt in DTS:
    errs = [results[H, dt, "lagr_linear"]["err100"] for H in Hs]
    assert errs == sorted(errs), (dt, errs)
