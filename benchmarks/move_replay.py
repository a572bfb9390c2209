"""The flow frame's particle moves of a real run, saved once and re-run on any checkout.

``save`` runs a scene (one process, outputs off) and saves the inputs of the
move kernel (``advect_p1_tables``: the particles' state, the velocities, the
fields' per-cell tables, the mesh arrays) of the moves ``--first`` to
``--first + --count - 1`` of the run into one file. ``replay`` re-runs those
moves with the kernel of the checkout it is started from, each from a copy of
its saved state, and prints per move the particles, the sub-steps, the median
time of ``--repeat`` runs and the sub-steps per second (the tables are the
saved ones: their making is not timed); ``--json`` writes them, ``--compare
FILE`` also checks that every move's end state equals the one in that earlier
replay's ``--state`` file to the bit (exit status 1 when one does not).

    python benchmarks/move_replay.py save rayleigh-taylor moves.pkl --first 40 --count 8
    python benchmarks/move_replay.py replay moves.pkl --state now.npz
    (cd ../pfem2x-before && PYTHONPATH=. python benchmarks/move_replay.py replay \\
        moves.pkl --compare ../pfem2x/now.npz)

The Rayleigh–Taylor scene (100 × 400, Courant 8) makes two moves a step (the
first pass on half the particles, the second on all of them), 68 in the run;
moves 40–47 are four steps' two passes (about 3 sub-steps per particle).
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

QUIET = (
    "output.every=0",
    "output.png=false",
    "output.fields=false",
    "output.particles=false",
)


def save(
    scene: str, path: Path, first: int, count: int, extra: list[str], variant: str | None = None
) -> int:
    """Run ``scene`` (``variant``) and save the inputs of the moves from ``first`` on."""
    import tempfile  # noqa: PLC0415

    import pfem2x.particles._kernels as K  # noqa: PLC0415
    from pfem2x import cli  # noqa: PLC0415

    orig = K.advect_p1_tables
    saved: list = []
    calls = [0]

    def wrapped(P, un, un1, du, T, S, M):  # noqa: N803
        if first <= calls[0] < first + count:
            saved.append(
                (
                    tuple(np.array(a) for a in P),
                    *(np.array(a) for a in (un, un1, du)),
                    tuple(np.array(a) for a in T),
                    tuple(S),
                    tuple(np.array(a) if isinstance(a, np.ndarray) else a for a in M),
                )
            )
        calls[0] += 1
        return orig(P, un, un1, du, T, S, M)

    args = ["run", scene, "--quiet", "--overwrite"]
    if variant:
        args += ["--variant", variant]
    for kv in (*QUIET, *extra):
        args += ["--set", kv]
    K.advect_p1_tables = wrapped
    try:
        with tempfile.TemporaryDirectory() as tmp:
            code = cli.main([*args, "--out", str(Path(tmp) / "run")])
    finally:
        K.advect_p1_tables = orig
    if code:
        if code != 2:  # exit 2: the run said what was wrong with its input
            print(f"error: the run of {scene} failed (exit {code})", file=sys.stderr)
        return 2
    if len(saved) < count:
        print(
            f"error: the run made {calls[0]} moves, fewer than --first + --count", file=sys.stderr
        )
        return 2
    with open(path, "wb") as f:
        pickle.dump(saved, f, protocol=pickle.HIGHEST_PROTOCOL)
    print(f"saved moves {first}..{first + count - 1} of {calls[0]} into {path}")
    return 0


def replay(
    path: Path, repeat: int, state: Path | None, compare: Path | None
) -> tuple[list[dict], bool | None]:
    """Re-run the saved moves with this checkout's kernel.

    Returns per move a dict of figures, and with ``compare`` whether every end
    state equals that file's to the bit (else None).
    """
    import pfem2x.particles._kernels as K  # noqa: PLC0415

    with open(path, "rb") as f:
        moves = pickle.load(f)

    def run(i: int) -> tuple[float, int, tuple]:
        P, un, un1, du, T, S, M = moves[i]
        st = K.MoveState(*(a.copy() for a in P))
        t0 = time.perf_counter()
        n = K.advect_p1_tables(st, un, un1, du, T, K.MoveParams(*S), K.MeshArrays(*M))
        return time.perf_counter() - t0, int(n), st

    run(0)  # load / compile the kernel
    rows, ends = [], {}
    for i in range(len(moves)):
        times = []
        for _ in range(repeat):
            t, n, st = run(i)
            times.append(t)
        t = float(np.median(times))
        S = K.MoveParams(*moves[i][5])
        rows.append(
            {
                "move": i,
                "particles": len(moves[i][0][0]),
                "blend": bool(S.blend),
                "substeps": n,
                "seconds": t,
                "substeps_per_s": n / t,
            }
        )
        for name, a in zip(K.MoveState._fields, st, strict=True):
            ends[f"{i}_{name}"] = a
    if state is not None:
        np.savez(state, **ends)
    same = None
    if compare is not None:
        ref = np.load(compare)
        if set(ref.files) != set(ends):
            raise ValueError("the end states of other moves")
        same = all(np.array_equal(ref[k], v) for k, v in ends.items())
        print("end states equal to", compare, "to the bit:", "yes" if same else "NO")
    return rows, same


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("save", help="run a scene and save the inputs of some of its moves")
    s.add_argument("scene")
    s.add_argument("file", type=Path)
    s.add_argument("--first", type=int, default=40)
    s.add_argument("--count", type=int, default=8)
    s.add_argument("--variant")
    s.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    r = sub.add_parser("replay", help="re-run the saved moves with this checkout's kernel")
    r.add_argument("file", type=Path)
    r.add_argument("--repeat", type=int, default=7)
    r.add_argument("--json", type=Path)
    r.add_argument("--state", type=Path, help="write the moves' end states (npz)")
    r.add_argument("--compare", type=Path, help="an earlier --state file to compare with")
    a = ap.parse_args(argv)
    if a.cmd == "save":
        if a.first < 0 or a.count < 1:
            print("error: --first must be >= 0 and --count >= 1", file=sys.stderr)
            return 2
        return save(a.scene, a.file, a.first, a.count, a.set, a.variant)
    for f in (a.file, a.compare):
        if f is not None and not f.is_file():
            print(f"error: {f}: no such file", file=sys.stderr)
            return 2
    if a.repeat < 1:
        print("error: --repeat must be >= 1", file=sys.stderr)
        return 2
    try:
        rows, same = replay(a.file, a.repeat, a.state, a.compare)
    except (OSError, EOFError, pickle.UnpicklingError, ValueError, TypeError, IndexError) as e:
        files = f"{a.file}" + (f" or {a.compare}" if a.compare is not None else "")
        print(f"error: {files}: not moves saved by 'save' or their states ({e})", file=sys.stderr)
        return 2
    print(f"{'move':>4} {'particles':>9} {'blend':>5} {'sub-steps':>9} {'ms':>8} {'M sub/s':>8}")
    for x in rows:
        print(
            f"{x['move']:>4} {x['particles']:>9} {x['blend']!s:>5} {x['substeps']:>9} "
            f"{1e3 * x['seconds']:>8.1f} {x['substeps_per_s'] / 1e6:>8.2f}"
        )
    total = sum(x["seconds"] for x in rows)
    steps = sum(x["substeps"] for x in rows)
    print(f"total {1e3 * total:.1f} ms, {steps / total / 1e6:.2f} M sub-steps/s")
    if a.json is not None:
        a.json.write_text(json.dumps({"moves": rows, "total_seconds": total}, indent=1) + "\n")
    return 1 if same is False else 0


if __name__ == "__main__":
    sys.exit(main())
