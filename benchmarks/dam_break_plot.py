"""Dam break: front and column height of runs against Martin & Moyce (1952).

Usage: ``python benchmarks/dam_break_plot.py OUT.png LABEL=RUN_DIR [LABEL=RUN_DIR ...]``
where each ``RUN_DIR`` holds the ``summary.json`` of a ``pfem2x run dam-break`` or the
``front.csv`` of an interFoam case (``benchmarks/interfoam_dambreak.py``). The title names
the mesh of the scene (100 x 50 cells) unless ``PFEM2X_PLOT_TITLE`` is set.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pfem2x.cases import MARTIN_MOYCE_FRONT, MARTIN_MOYCE_HEIGHT  # noqa: E402


def _curves(path: Path) -> tuple[np.ndarray, np.ndarray, bool]:
    """[[T, Z]], [[tau, H]] and whether it ran to the end, of a pfem2x run or an
    interFoam case's ``front.csv``."""
    if (path / "front.csv").is_file():
        rows = np.loadtxt(path / "front.csv", delimiter=",", skiprows=1, ndmin=2)
        return rows[:, [1, 2]], rows[:, [3, 4]], True
    s = json.loads((path / "summary.json").read_text())
    m = s["metrics"]
    return np.array(m["front"]), np.array(m["height"]), s["status"] == "ok"


def main(out: str, runs: list[str]) -> None:
    """Plot ``metrics.front`` / ``metrics.height`` of each run with the reference points."""
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6), dpi=90)
    a1.plot(*MARTIN_MOYCE_FRONT.T, "ko", ms=4, label="Martin & Moyce (1952)")
    a2.plot(*MARTIN_MOYCE_HEIGHT.T, "ko", ms=4, label="Martin & Moyce (1952)")
    for spec in runs:
        label, path = spec.split("=", 1)
        front, height, ok = _curves(Path(path))
        if not ok:
            label += f" (diverged at T = {front[-1, 0]:.2f})"
        a1.plot(*front.T, "-", label=label)
        a2.plot(*height.T, "-", label=label)
    a1.set(xlabel="T = t (2g/a)$^{1/2}$", ylabel="front Z = x/a", xlim=(0, 3.5), ylim=(1, 4.8))
    a2.set(xlabel=r"$\tau$ = t (g/a)$^{1/2}$", ylabel="height H = h/(2a)", xlim=(0, 2.5))
    a2.set_ylim(0.3, 1.02)
    a1.legend(fontsize=7)
    a2.legend(fontsize=7)
    for a in (a1, a2):
        a.grid(alpha=0.3)
    title = "dam break, column a x 2a, water/air 1000:1, 100x50 cells (H = a/20)"
    fig.suptitle(os.environ.get("PFEM2X_PLOT_TITLE", title), fontsize=9)
    fig.tight_layout()
    fig.savefig(out)


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1].startswith("-"):
        usage = __doc__.strip().splitlines()[2].replace("``", "").replace("Usage:", "usage:")
        print(usage, file=sys.stderr)
        sys.exit(2)
    main(sys.argv[1], sys.argv[2:])
