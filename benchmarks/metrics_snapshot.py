"""Run every built-in scene in every frame it supports and collect the metrics.

A regression check for changes that must not move any result: run it once
before and once after, then compare.

    python benchmarks/metrics_snapshot.py run --out before.json
    python benchmarks/metrics_snapshot.py run --out after.json
    python benchmarks/metrics_snapshot.py compare before.json after.json

The runs are each built-in scene's ``small`` variant in every frame of its
physics (transport: lagrangian, eulerian, characteristic; flow: lagrangian,
eulerian) and the default of each transport scene in every frame. ``compare``
prints one line per run with the largest relative metric difference and exits
1 if any metric differs by more than ``--rtol`` (default 0: bit-identical).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "pfem2x" / "scenes"
FRAMES = {
    "transport": ("lagrangian", "eulerian", "characteristic"),
    "flow": ("lagrangian", "eulerian"),
}


def cases(full: bool) -> list[tuple[str, str, str | None]]:
    """``(scene, frame, variant)`` of every run."""
    out = []
    for path in sorted(SCENES.glob("*.toml")):
        data = tomllib.loads(path.read_text(encoding="utf-8"))
        physics = data["scene"]["physics"]
        for frame in FRAMES[physics]:
            if "small" in data.get("variants", {}):
                out.append((path.stem, frame, "small"))
            if physics == "transport" and full:
                out.append((path.stem, frame, None))
    return out


def run_all(out: Path, full: bool) -> None:
    """Run every case serially and write ``{case: {status, steps, metrics}}`` to ``out``."""
    result = {}
    env = dict(os.environ, OMP_NUM_THREADS="1")
    with tempfile.TemporaryDirectory() as tmp:
        for scene, frame, variant in cases(full):
            key = f"{scene}/{frame}/{variant or 'default'}"
            run_dir = Path(tmp) / key.replace("/", "_")
            cmd = [sys.executable, "-m", "pfem2x", "run", scene, "--quiet", "--out", str(run_dir)]
            cmd += ["--set", f'method.frame="{frame}"']
            if variant:
                cmd += ["--variant", variant]
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
            summary_file = run_dir / "summary.json"
            if summary_file.is_file():
                s = json.loads(summary_file.read_text(encoding="utf-8"))
                result[key] = {"status": s["status"], "steps": s["steps"], "metrics": s["metrics"]}
            else:
                result[key] = {"status": f"exit {proc.returncode}", "steps": 0, "metrics": {}}
            print(f"{key}: {result[key]['status']} ({proc.returncode})", file=sys.stderr)
    out.write_text(json.dumps(result, indent=1, sort_keys=True), encoding="utf-8")


def _rel(a: object, b: object) -> float:
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return math.inf
        return max((_rel(x, y) for x, y in zip(a, b, strict=True)), default=0.0)
    if isinstance(a, int | float) and isinstance(b, int | float):
        if a == b:
            return 0.0
        return abs(a - b) / max(abs(a), abs(b), 1e-300)
    return 0.0 if a == b else math.inf


def compare(before: Path, after: Path, rtol: float) -> int:
    """Print the largest relative difference of each run; 1 if any exceeds ``rtol``."""
    a = json.loads(before.read_text(encoding="utf-8"))
    b = json.loads(after.read_text(encoding="utf-8"))
    bad = 0
    print("| run | status | steps | metrics | max rel. difference |\n|---|---|---|---|---|")
    for key in sorted(set(a) | set(b)):
        ra, rb = a.get(key), b.get(key)
        if ra is None or rb is None:
            print(f"| {key} | only in {'after' if ra is None else 'before'} | | | |")
            bad += 1
            continue
        keys = set(ra["metrics"]) | set(rb["metrics"])
        diff = max((_rel(ra["metrics"].get(k), rb["metrics"].get(k)) for k in keys), default=0.0)
        same = ra["status"] == rb["status"] and ra["steps"] == rb["steps"]
        bad += (not same) or diff > rtol
        print(f"| {key} | {rb['status']} | {rb['steps']} | {len(keys)} | {diff:.2e} |")
    print(f"\n{bad} run(s) differ beyond rtol = {rtol:g}")
    return 1 if bad else 0


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--small-only", action="store_true", help="skip the transport defaults")
    c = sub.add_parser("compare")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--rtol", type=float, default=0.0)
    args = p.parse_args()
    if args.cmd == "run":
        run_all(args.out, not args.small_only)
        return 0
    return compare(args.before, args.after, args.rtol)


if __name__ == "__main__":
    raise SystemExit(main())
