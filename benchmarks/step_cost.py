"""Cost per time step of every built-in scene in every frame, two checkouts side by side.

The scenes as shipped (their default variant, their own Courant number and
mesh), with the pictures, fields and particle files off so that only the
time stepping is compared. Each run reports the median wall time of one
step (``step_wall_median`` of summary.json) and the CPU time of the whole
time stepping divided by the number of steps. The checkouts alternate run by
run, ``--repeat`` times, and the table gives the medians and the ratio of
the two in each row (the last checkout's CPU time per step against the first's: on a
shared machine the CPU time is less disturbed by other jobs than the wall time).

    python benchmarks/step_cost.py run --checkout before=OLD_CHECKOUT --checkout now=. \
        --repeat 3 --out step_cost.json
    python benchmarks/step_cost.py table step_cost.json > step_cost.md

``--scene NAME`` (repeatable) runs only those scenes, ``--scene NAME:VARIANT`` a
variant of one; ``--frame`` only those frames. Each run also reports its set-up
seconds (``setup_seconds``: mesh, forms, particles, initial fields), a column of
the table.

A checkout is a folder holding a ``pfem2x`` package (e.g. ``git worktree add``
of an earlier commit, its particle kernels compiled once with
``python -m pfem2x.jit``). Only scenes present in every checkout are run.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

FRAMES = {
    "transport": ("lagrangian", "eulerian", "characteristic"),
    "flow": ("lagrangian", "eulerian"),
}
QUIET_OUTPUT = (
    "output.png=false",
    "output.fields=false",
    "output.particles=false",
)


def scenes(
    checkouts: dict[str, Path], only: list[str] | None = None, frames: list[str] | None = None
) -> list[tuple[str, str]]:
    """``(scene, frame)`` of every scene present in every checkout, in every frame.

    ``only``: those scenes (``NAME`` or ``NAME:VARIANT``); ``frames``: those frames.
    """
    names = None
    for root in checkouts.values():
        here = {p.stem for p in (root / "pfem2x" / "scenes").glob("*.toml")}
        names = here if names is None else names & here
    first = next(iter(checkouts.values()))
    wanted = only or sorted(names or ())
    out = []
    for item in wanted:
        name = item.partition(":")[0]
        if name not in (names or ()):
            raise ValueError(f"--scene {item}: no such scene in every checkout")
        text = (first / "pfem2x" / "scenes" / f"{name}.toml").read_text(encoding="utf-8")
        physics = tomllib.loads(text)["scene"]["physics"]
        out.extend((item, f) for f in FRAMES[physics] if not frames or f in frames)
    return out


def run_one(root: Path, scene: str, frame: str, tmp: Path) -> dict:
    """Run ``scene`` (``NAME[:VARIANT]``) in ``frame`` with the package of ``root``: its cost."""
    env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=str(root))
    name, _, variant = scene.partition(":")
    out = tmp / f"{name}-{variant}-{frame}"
    cmd = [sys.executable, "-m", "pfem2x", "run", name, "--quiet", "--overwrite"]
    cmd += ["--variant", variant] if variant else []
    cmd += ["--out", str(out), "--set", f'method.frame="{frame}"']
    for kv in QUIET_OUTPUT:
        cmd += ["--set", kv]
    proc = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True, check=False)
    path = out / "summary.json"
    if not path.is_file():
        return {"status": f"exit {proc.returncode}", "steps": 0}
    s = json.loads(path.read_text(encoding="utf-8"))
    steps = max(int(s["steps"]), 1)
    return {
        "status": s["status"],
        "steps": int(s["steps"]),
        "step_wall_median": float(s["step_wall_median"]),
        "cpu_per_step": float(s["cpu_seconds"]) / steps,
        "setup_seconds": float(s["setup_seconds"]),
    }


def run_all(checkouts: dict[str, Path], repeat: int, out: Path, cases: list) -> None:
    """Alternate the checkouts run by run; write every sample to ``out`` (JSON)."""
    result: dict[str, dict[str, list[dict]]] = {f"{s}/{f}": {} for s, f in cases}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeat):
            for scene, frame in cases:
                for label, root in checkouts.items():
                    r = run_one(root, scene, frame, Path(tmp))
                    result[f"{scene}/{frame}"].setdefault(label, []).append(r)
                    print(f"{label} {scene}/{frame}: {r}", file=sys.stderr)
                    out.write_text(json.dumps(result, indent=1), encoding="utf-8")


def table(path: Path) -> str:
    """Markdown table of the medians; the ratio is the last checkout's against the first's."""
    data = json.loads(path.read_text(encoding="utf-8"))
    labels = list(next(iter(data.values())))
    head = ["scene / frame", "steps"]
    for label in labels:
        head += [f"{label}: ms per step (median)", f"{label}: CPU ms per step"]
        head += [f"{label}: set-up s"]
    head += [f"{labels[-1]} / {labels[0]} (CPU)"]
    rows = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for case, runs in data.items():
        cells = [case, "/".join(str(runs[la][0]["steps"]) for la in labels)]
        med = {}
        for label in labels:
            ok = [r for r in runs[label] if r["status"] == "ok"]
            if not ok:
                cells += [runs[label][0]["status"], "", ""]
                continue
            wall = statistics.median(r["step_wall_median"] for r in ok)
            med[label] = statistics.median(r["cpu_per_step"] for r in ok)
            cells += [f"{1e3 * wall:.3g}", f"{1e3 * med[label]:.3g}"]
            setup = [r["setup_seconds"] for r in ok if "setup_seconds" in r]
            cells.append(f"{statistics.median(setup):.2f}" if setup else "")
        ratio = med[labels[-1]] / med[labels[0]] if len(med) == len(labels) else float("nan")
        cells.append(f"{ratio:.2f}")
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument(
        "--checkout",
        action="append",
        required=True,
        metavar="LABEL=DIR",
        help="a label and a folder holding a pfem2x package (give two or more)",
    )
    r.add_argument("--repeat", type=int, default=3)
    r.add_argument("--scene", action="append", metavar="NAME[:VARIANT]", help="only these")
    r.add_argument("--frame", action="append", choices=sorted({*FRAMES["transport"]}))
    r.add_argument("--out", type=Path, required=True)
    t = sub.add_parser("table")
    t.add_argument("json", type=Path)
    args = p.parse_args()
    if args.cmd == "table":
        print(table(args.json))
        return 0
    checkouts = {}
    for item in args.checkout:
        label, sep, folder = item.partition("=")
        root = Path(folder).resolve()
        if not sep or not (root / "pfem2x" / "scenes").is_dir():
            print(f"error: --checkout {item}: expected LABEL=DIR with DIR/pfem2x", file=sys.stderr)
            return 2
        checkouts[label] = root
    try:
        cases = scenes(checkouts, args.scene, args.frame)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    run_all(checkouts, args.repeat, args.out, cases)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
