"""Cost of the 2D PNG snapshots in a fresh process, checkouts side by side.

Each run is a new Python process (as a run's first picture pays for the drawing
library's import and the mesh's pixel weights) that draws six snapshots of a
Rayleigh–Taylor-like field on a rectangle of ``--cells`` (the scene's box, two
triangles per cell, values 3 above the interface ``y = 0.1 cos(2 pi x)`` and 1
below, the interface as 2,000 segments) with ``pfem2x.picture.png_2d``, and
reports the seconds of the first snapshot (import included), the median of the
other five and the six together. The checkouts alternate run by run::

    python benchmarks/picture.py --checkout before=../pfem2x-before --checkout now=. \\
        --repeat 5 --json picture.json --md picture.md

A checkout is a folder holding a ``pfem2x`` package (e.g. ``git worktree add`` of an
earlier commit). Timings are for comparing checkouts on one machine; speed targets
live in docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: What each child process runs: argv = checkout, nx, ny, folder; prints a JSON line.
CHILD = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
nx, ny, out = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
x, y = np.linspace(-0.5, 0.5, nx + 1), np.linspace(-2.0, 2.0, ny + 1)
P = np.stack(np.meshgrid(x, y, indexing="ij"), -1)
a, b = P[:-1, :-1].reshape(-1, 2), P[1:, :-1].reshape(-1, 2)
c, d = P[1:, 1:].reshape(-1, 2), P[:-1, 1:].reshape(-1, 2)
coords = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
vals = np.where(coords[..., 1] > 0.1 * np.cos(2 * np.pi * coords[..., 0]), 3.0, 1.0)
xs = np.linspace(-0.5, 0.5, 2001)
line = np.stack([xs, 0.1 * np.cos(2 * np.pi * xs)], 1)
segs = np.stack([line[:-1], line[1:]], 1)
t1 = time.perf_counter()
from pfem2x.picture import png_2d
ends = []
for k in range(6):
    png_2d(f"{out}/s{k}.png", coords, vals, f"density t = {k}", None, None, "density", segs)
    ends.append(time.perf_counter())
each = sorted(b - a for a, b in zip(ends[:-1], ends[1:]))
print(json.dumps({"first": ends[0] - t1, "next": each[2], "six": ends[-1] - t1}))
"""


def run_once(python: str, checkout: Path, cells: tuple[int, int]) -> dict[str, float]:
    """One fresh process drawing six snapshots with ``checkout``'s picture module."""
    with tempfile.TemporaryDirectory() as tmp:
        res = subprocess.run(
            [python, "-c", CHILD, str(checkout.resolve()), str(cells[0]), str(cells[1]), tmp],
            capture_output=True,
            text=True,
            check=False,
            cwd=tmp,
        )
    if res.returncode != 0:
        raise RuntimeError(f"{checkout}: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def markdown(rows: dict[str, list[dict[str, float]]], cells: tuple[int, int]) -> str:
    """The medians per checkout."""
    lines = [
        f"Six 2D snapshots on {cells[0]} x {cells[1]} cells, a fresh process each run, "
        "medians (ranges), seconds:",
        "",
        "| checkout | runs | first (with the import) | each further | six |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, runs in rows.items():
        cell = []
        for key in ("first", "next", "six"):
            v = [r[key] for r in runs]
            cell.append(f"{statistics.median(v):.3f} ({min(v):.3f}–{max(v):.3f})")
        lines.append(f"| {name} | {len(runs)} | " + " | ".join(cell) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module's docstring."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkout", action="append", default=[], metavar="NAME=PATH")
    ap.add_argument("--cells", nargs=2, type=int, default=[100, 400], metavar=("NX", "NY"))
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--json", type=Path, help="write every run and the medians here")
    ap.add_argument("--md", type=Path, help="write the markdown table here")
    args = ap.parse_args(argv)
    checkouts: dict[str, Path] = {}
    for item in args.checkout or ["now=."]:
        name, sep, path = item.partition("=")
        if not sep or not (Path(path) / "pfem2x" / "picture.py").is_file():
            print(
                f"error: --checkout {item!r}: NAME=PATH of a folder holding pfem2x/",
                file=sys.stderr,
            )
            return 2
        checkouts[name] = Path(path)
    cells = (args.cells[0], args.cells[1])
    rows: dict[str, list[dict[str, float]]] = {name: [] for name in checkouts}
    for _ in range(args.repeat):
        for name, path in checkouts.items():
            rows[name].append(run_once(args.python, path, cells))
    md = markdown(rows, cells)
    print(md, end="")
    if args.json:
        args.json.write_text(json.dumps({"cells": cells, "runs": rows}, indent=1) + "\n")
    if args.md:
        args.md.write_text(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
