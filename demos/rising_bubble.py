# ---
# jupyter:
#   jupytext:
#     text_representation:
#       extension: .py
#       format_name: percent
# ---

# %% [markdown]
# # Rising bubble (Hysing et al. 2009, test case 1) against MooNMD's curves
#
# A bubble of radius 0.25 (ρ 100, μ 1) rises in a 1 × 2 box of liquid (ρ 1000,
# μ 10) under g = 0.98 with surface tension σ = 24.5 (scene `rising-bubble`).
# The benchmark's quantities are the bubble's centroid height, its mean rise
# velocity and its circularity over 0 ≤ t ≤ 3; the reference is the time series
# of the group MooNMD (the package's `data/moonmd_case1.csv`, from
# `docs/data/rising-bubble/moonmd/`), and its outline at t = 3.
#
# Both frames at h = 1/40, each at Δt = 0.02 (the level set's step in the
# scene, Courant ≈ 0.4 by the largest speed) and at the flow's Courant number 2
# re-evaluated every step (PFEM-2's own step at this mesh, Δt 0.11–0.24, 14–32 ×
# the explicit capillary limit; `flow.capillary_increment` and the
# Laplace–Beltrami term of the normal velocity, `flow.capillary_damping =
# "normal"`, and for PFEM-2 its frame's two passes). The table gives the curve
# errors (`*_curve_error`: the largest differences to MooNMD over the run) and
# the wall time: what accuracy costs in time.
#
#     python demos/rising_bubble.py        # under half a minute on one core
#
# Writes `rising_bubble.md` and `rising_bubble.png` under `$PFEM2X_DEMO_OUT`
# (default `runs/demos/`) in `hysing_bubble/`. `PFEM2X_DEMO_SMALL=1` uses the
# scene's small variant (20 × 40 cells, to t = 0.4).

# %%
import os
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from mpi4py import MPI

from pfem2x.cases import BUBBLE_SERIES, curve_errors, moonmd_series
from pfem2x.runner import Simulation
from pfem2x.scene import load_scene

small = os.environ.get("PFEM2X_DEMO_SMALL") == "1"
# (not named "rising-bubble": a folder of the scene's name would shadow it)
out = Path(os.environ.get("PFEM2X_DEMO_OUT", "runs/demos")) / "hysing_bubble"
comm = MPI.COMM_WORLD
rank0 = comm.rank == 0
variant = "small" if small else "h40"
SMALL_STEP = ["time.dt=0.02"]
LARGE = ["time.courant=2", "time.adaptive=true"]  # PFEM-2's frame table has the rest
CAPILLARY = ["flow.capillary_increment=true", 'flow.capillary_damping="normal"']
#: label -> scene overrides
RUNS = {
    "level set, Δt = 0.02": ['method.frame="eulerian"', *SMALL_STEP],
    "PFEM-2, Δt = 0.02": ['method.frame="lagrangian"', *SMALL_STEP],
    "level set, Courant 2": ['method.frame="eulerian"', *LARGE, *CAPILLARY],
    "PFEM-2, Courant 2": ['method.frame="lagrangian"', *LARGE],
}
OFF = ["output.png=false", "output.every=0", "output.fields=false", "output.particles=false"]
OFF += ["output.png_times=[]"]

# %% [markdown]
# Each run's diagnostics (one row per step) hold the three quantities; the
# summary's metrics hold the curve errors when a run reaches t = 3 (here they
# are computed from the history for any end time, up to t = 3).

# %%
ref = moonmd_series(1)


def run(label: str, overrides: list[str]) -> dict:
    """One run: its history, status, wall time and the interface at the end."""
    tag = label.replace(" ", "_").replace(",", "").replace("'", "")
    scene = load_scene("rising-bubble", overrides + OFF, variant=variant)
    res = Simulation(scene, out / "runs" / tag, comm, quiet=True, overwrite=True).run()
    h = res.history
    t = np.array([d["t"] for d in h])
    vals = {k: np.array([d[k] for d in h]) for k in BUBBLE_SERIES}
    last = sorted((out / "runs" / tag / "interface").glob("interface_t*.csv"))[-1]
    return {
        "t": t,
        "vals": vals,
        "errors": curve_errors(t, vals, ref),
        "status": res.status,
        "steps": res.summary["steps"],
        "dt": float(res.summary["dt"]),
        "wall": float(res.summary["wall_seconds"]),
        "interface": np.loadtxt(last, delimiter=",", skiprows=1, ndmin=2),
    }


results = {label: run(label, ov) for label, ov in RUNS.items()}

# %% [markdown]
# The table: curve errors against MooNMD (centroid height, rise velocity,
# circularity) and the wall time of each run.

# %%
head = ["run", "steps", "Δt", "status", "max \\|Δy_c\\|", "max \\|Δu_c\\|", "max \\|Δcirc.\\|"]
head += ["wall s"]
md = "| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n"
for label, r in results.items():
    e = r["errors"]
    cells = [label, str(r["steps"]), f"{r['dt']:.3g}", r["status"]]
    cells += [f"{e[f'{k}_curve_error']:.4f}" for k in BUBBLE_SERIES] + [f"{r['wall']:.1f}"]
    md += "| " + " | ".join(cells) + " |\n"
t_end = max(r["t"][-1] for r in results.values())
md += (
    f"\n{'20 × 40' if small else '40 × 80'} cells, to t = {t_end:g}; {comm.size} process(es);"
    " curve errors: the largest differences to MooNMD at the run's step times.\n"
)
if rank0:
    print(md)
    out.mkdir(parents=True, exist_ok=True)
    (out / "rising_bubble.md").write_text(md)

# %% [markdown]
# The three quantities against t with MooNMD's curves (dashed), and the
# interfaces at the end (with MooNMD's outline at t = 3 when the runs get there).

# %%
if rank0:
    fig, axes = plt.subplots(1, 4, figsize=(15, 3.8), dpi=80)
    names = {"centroid_y": "centroid height", "rise_velocity": "rise velocity"}
    for ax, k in zip(axes[:3], BUBBLE_SERIES, strict=True):
        sel = ref["t"] <= t_end + 1e-9
        ax.plot(ref["t"][sel], ref[k][sel], "k--", lw=1, label="MooNMD")
        for label, r in results.items():
            ax.plot(r["t"], r["vals"][k], "-", lw=1.2, label=label)
        ax.set(xlabel="t", title=names.get(k, k))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    ax = axes[3]
    colors = [line.get_color() for line in axes[0].get_lines()[1:]]  # the runs' colours
    for r, color in zip(results.values(), colors, strict=True):
        d = r["interface"]
        for line in np.unique(d[:, 0]):
            seg = d[d[:, 0] == line]
            ax.plot(seg[:, 1], seg[:, 2], "-", lw=1, color=color)
    shape = Path(__file__).resolve().parents[1] / "docs/data/rising-bubble/moonmd/c1g3l4s.txt"
    if abs(t_end - 3.0) < 1e-9 and shape.exists():
        ax.plot(*np.loadtxt(shape).T, "k--", lw=1)
    ax.set(aspect="equal", xlim=(0, 1), title=f"interfaces at t = {t_end:g}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / "rising_bubble.png")
