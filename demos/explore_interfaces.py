# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Exploring interface snapshots of Rayleigh–Taylor runs
#
# Two-phase runs write the interface (phase = ½) as polylines at every field
# output (`interface/interface_t*.csv`) and the tip positions in
# `summary.json`. This notebook-style script loads finished runs, overlays their
# interfaces (matplotlib, and pyvista off-screen) and plots the tips against the
# interFoam reference in `docs/data/rt-reference/interfoam/`.
#
# Point `RUNS` at your own run folders (e.g. made with
# `pfem2x run rayleigh-taylor --set time.courant=8 --out runs/rt-co8`). Without
# them it makes two small runs first (PFEM-2 at two Courant numbers), which is
# what the test suite does (`PFEM2X_DEMO_SMALL=1`). Convert to a notebook with
# `jupytext --to notebook demos/explore_interfaces.py`.

# %%
import json
import os
from pathlib import Path

import matplotlib

matplotlib.use(os.environ.get("MPLBACKEND", "Agg"))
import matplotlib.pyplot as plt
import numpy as np
from mpi4py import MPI

from pfem2x.io import read_interface

comm = MPI.COMM_WORLD
small = os.environ.get("PFEM2X_DEMO_SMALL") == "1"
out_root = Path(os.environ.get("PFEM2X_DEMO_OUT", "runs/demos")) / "explore"
RUNS: dict[str, Path] = {}  # label -> run folder; fill in to explore your own runs

# %% [markdown]
# ## Make two runs if none were given

# %%
if not RUNS:
    from pfem2x.runner import Simulation
    from pfem2x.scene import load_scene

    cells = "[16,64]" if small else "[50,200]"
    t_end = 0.70710678 if small else 2.8284271  # tau = 0.5 / 2
    for courant in (1.0, 4.0):
        scene = load_scene(
            "rayleigh-taylor",
            [
                f"mesh.cells={cells}",
                f"time.t_end={t_end}",
                f"time.courant={courant}",
                f"output.every={t_end / 2}",
                "output.png=false",
                "output.particles=false",
            ],
        )
        label = f"PFEM-2 Co {courant:g}"
        Simulation(scene, out_root / f"co{courant:g}", comm, quiet=True, overwrite=True).run()
        RUNS[label] = out_root / f"co{courant:g}"

# %% [markdown]
# ## Load interfaces and tips

# %%
snapshots = {}
tips = {}
for label, folder in RUNS.items():
    files = sorted((folder / "interface").glob("interface_t*.csv"))
    snapshots[label] = {float(f.stem.split("_t")[1]): read_interface(f) for f in files}
    summary = json.loads((folder / "summary.json").read_text())
    tips[label] = (
        np.array(summary["metrics"]["tip_falling"]),
        np.array(summary["metrics"]["tip_rising"]),
    )
    print(
        f"{label}: {len(files)} snapshots, status {summary['status']}"
    ) if comm.rank == 0 else None

# %% [markdown]
# ## Overlay the last interface of every run (matplotlib)

# %%
if comm.rank == 0:
    fig, ax = plt.subplots(figsize=(3.5, 7))
    for (label, snaps), color in zip(snapshots.items(), ["C0", "C3", "C2", "C1"], strict=False):
        t_last = max(snaps)
        for i, line in enumerate(snaps[t_last]):
            ax.plot(line[:, 0], line[:, 1], color=color, lw=1.2, label=label if i == 0 else None)
    ax.set_aspect("equal")
    ax.set_xlim(-0.5, 0.5)
    ax.legend(fontsize=8)
    ax.set_title("interface at the last output")
    fig.savefig(out_root / "interfaces.png", dpi=110, bbox_inches="tight")
    plt.close(fig)

# %% [markdown]
# ## The same with pyvista (off-screen), as lines in 3D space

# %%
if comm.rank == 0:
    from pfem2x.io import pyvista_usable, quiet_vtk

    if pyvista_usable():
        import pyvista as pv

        quiet_vtk()
        pl = pv.Plotter(off_screen=True, window_size=(400, 900))
        for (_label, snaps), color in zip(snapshots.items(), ["blue", "red"], strict=False):
            for line in snaps[max(snaps)]:
                pts = np.column_stack([line, np.zeros(len(line))])
                pl.add_mesh(pv.lines_from_points(pts), color=color, line_width=3)
        pl.view_xy()
        pl.screenshot(str(out_root / "interfaces_pyvista.png"))
        pl.close()

# %% [markdown]
# ## Tip positions against the interFoam reference (Tryggvason time τ)

# %%
import pfem2x  # noqa: E402

# the stored interFoam tip histories ship with the repository
repo = Path(pfem2x.__file__).resolve().parents[1]
reference = repo / "docs/data/rt-reference/interfoam/tips_all.csv"
if comm.rank == 0:
    fig, ax = plt.subplots(figsize=(6, 4))
    for label, (fall, rise) in tips.items():
        ax.plot(fall[:, 0], fall[:, 1], label=f"{label} falling")
        ax.plot(rise[:, 0], rise[:, 1], "--", label=f"{label} rising")
    if reference.is_file():
        ref = np.genfromtxt(reference, delimiter=",", names=True)
        ax.plot(ref["tT"], ref["r100_dt0001spike"], "k:", label="interFoam 100x400")
        ax.plot(ref["tT"], ref["r100_dt0001bubble"], "k:")
    ax.set_xlabel("tau")
    ax.set_ylabel("y of the tip")
    ax.set_xlim(0, max(f[-1, 0] for f, _ in tips.values()))
    lo = min(f[:, 1].min() for f, _ in tips.values())
    hi = max(r[:, 1].max() for _, r in tips.values())
    ax.set_ylim(lo - 0.1 * (hi - lo), hi + 0.1 * (hi - lo))
    ax.legend(fontsize=7)
    fig.savefig(out_root / "tips.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    print("wrote", sorted(p.name for p in out_root.glob("*.png")))

# %%
# Every run produced an interface from wall to wall at every output.
for label, snaps in snapshots.items():
    assert len(snaps) >= 2, label
    for t, lines in snaps.items():
        xs = np.concatenate([ln[:, 0] for ln in lines])
        assert xs.min() < -0.49 and xs.max() > 0.49, (label, t)
