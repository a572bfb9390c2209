"""Rayleigh-Taylor tips side by side: pfem2x runs against interFoam runs, at tau = 1 ... 2.5.

Usage::

    python benchmarks/rt_reference.py [--stored-dir DIR] [--stored COL ...]
        [--case NAME=DIR ...] [--run NAME=DIR ...] [--ref NAME]
        [--md FILE] [--json FILE]

Sources of tip histories (spike = lowest, bubble = highest point of the interface,
against Tryggvason time tau):

* ``--stored COL``: a stored interFoam run of ``docs/data/rt-reference/interfoam/tips_all.csv``
  (columns ``COL:spike`` / ``COL:bubble`` against ``tT``), e.g. ``r100_dt0.001``;
* ``--case NAME=DIR``: an interFoam case with its ``tips.csv`` (columns ``tau`` or ``tT``,
  ``y_spike``, ``y_bubble``), as ``benchmarks/interfoam_case.py run`` / ``tips`` write it;
* ``--run NAME=DIR``: a ``pfem2x run`` output folder (``summary.json``:
  ``metrics.tip_falling`` / ``tip_rising`` as ``[tau, y]``, plus frame, steps, dt,
  largest Courant number and CPU seconds).

Every history is interpolated linearly in tau at 1, 1.5, 2, 2.5 (a source that does
not reach a time gets no value there). ``d2`` / ``d25`` = the largest ``|y - y_ref|``
over both tips up to tau = 2 / 2.5 against ``--ref`` (default: the stored
``r100_dt0.001``, interFoam 100 x 400 at dt = 0.001); ``a2`` / ``a25`` the same at every
time of the source's own history (the reference interpolated there, within its range),
which for a ``pfem2x run`` are its output times. Prints a markdown table; ``--md`` /
``--json`` also write it.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

TAUS = (1.0, 1.5, 2.0, 2.5)
HERE = Path(__file__).resolve().parent
STORED_DIR = HERE.parent / "docs" / "data" / "rt-reference" / "interfoam"


def _fail(msg: str) -> None:
    print(f"error: {msg}", file=sys.stderr)
    raise SystemExit(2)


def _pair(text: str, flag: str) -> tuple[str, Path]:
    name, sep, path = text.partition("=")
    if not sep or not name or not path:
        _fail(f"{flag} {text!r}: expected NAME=DIR")
    return name, Path(path)


def _history(
    ts: np.ndarray, spike: np.ndarray, tb: np.ndarray, bubble: np.ndarray
) -> dict[str, Any]:
    """The tips at 1 ... 2.5 and the whole history (``_hist``, not written to JSON)."""
    return {
        "spike": _at(ts, spike),
        "bubble": _at(tb, bubble),
        "_hist": {"spike": (ts, spike), "bubble": (tb, bubble)},
    }


def _at(tau: np.ndarray, y: np.ndarray) -> list[float | None]:
    tol = 1e-6  # the last output of a run to tau = 2.5 may be at 2.4999999
    return [float(np.interp(t, tau, y)) if tau[0] <= t <= tau[-1] + tol else None for t in TAUS]


def stored(folder: Path, col: str) -> dict[str, Any]:
    """Tips of a stored interFoam run (``tips_all.csv`` in ``folder``)."""
    path = folder / "tips_all.csv"
    if not path.is_file():
        _fail(f"--stored-dir: {path} not found")
    with open(path) as f:
        rows = list(csv.DictReader(f))
    if f"{col}:spike" not in rows[0]:
        _fail(f"--stored {col}: no such run in {path}")
    tau = np.array([float(r["tT"]) for r in rows])
    sp = np.array([float(r[f"{col}:spike"]) for r in rows])
    bu = np.array([float(r[f"{col}:bubble"]) for r in rows])
    return {"code": "interFoam (stored)", **_history(tau, sp, tau, bu)}


def foam_case(path: Path) -> dict[str, Any]:
    """Tips of an interFoam case from its ``tips.csv``."""
    f = path / "tips.csv"
    if not f.is_file():
        _fail(f"--case: {f} not found (run benchmarks/interfoam_case.py tips on the case)")
    a = np.genfromtxt(f, delimiter=",", names=True)
    tau = a["tau"] if "tau" in a.dtype.names else a["tT"]
    return {"code": "interFoam", **_history(tau, a["y_spike"], tau, a["y_bubble"])}


def pfem2x_run(path: Path) -> dict[str, Any]:
    """Tips and cost of a ``pfem2x run`` output folder."""
    f = path / "summary.json"
    if not f.is_file():
        _fail(f"--run: {f} not found")
    s = json.loads(f.read_text())
    m = s.get("metrics", {})
    if "tip_falling" not in m:
        _fail(f"--run: {f} has no metrics.tip_falling (not a Rayleigh-Taylor run?)")
    fa, ri = np.array(m["tip_falling"]), np.array(m["tip_rising"])
    return {
        "code": "pfem2x " + ("PFEM-2" if s.get("frame") == "lagrangian" else "level set"),
        **_history(fa[:, 0], fa[:, 1], ri[:, 0], ri[:, 1]),
        "steps": s.get("steps"),
        "dt": s.get("dt") if not s.get("adaptive_dt") else f"{s.get('dt_min'):.2g}..",
        "courant_max": m.get("courant_max"),
        "cpu_s": s.get("cpu_seconds"),
        "status": s.get("status"),
    }


def differences(row: dict[str, Any], ref: dict[str, Any]) -> None:
    """Add ``d2`` / ``d25`` (at 1 ... 2.5) and ``a2`` / ``a25`` (at the row's own times)."""
    for key, upto in (("d2", 2.0), ("d25", 2.5)):
        diffs = [
            abs(row[k][i] - ref[k][i])
            for k in ("spike", "bubble")
            for i, t in enumerate(TAUS)
            if t <= upto and row[k][i] is not None and ref[k][i] is not None
        ]
        row[key] = max(diffs) if diffs else None
    tol = 1e-6
    for key, upto in (("a2", 2.0), ("a25", 2.5)):
        diffs = []
        for k in ("spike", "bubble"):
            t, y = row["_hist"][k]
            tr, yr = ref["_hist"][k]
            sel = (t <= upto + tol) & (t >= tr[0]) & (t <= tr[-1] + tol)
            if sel.any():
                diffs.append(float(np.max(np.abs(y[sel] - np.interp(t[sel], tr, yr)))))
        row[key] = max(diffs) if diffs else None


def table(rows: dict[str, dict[str, Any]], ref: str) -> str:
    def f(v: Any, nd: int = 3) -> str:
        if v is None:
            return "–"
        if isinstance(v, float):
            return f"{v:.{nd}f}" if abs(v) < 100 else f"{v:.0f}"
        return str(v)

    head = ["source", "code", "steps", "Δt", "Co max", "CPU s"]
    head += [f"τ={t:g} spike / bubble" for t in TAUS] + [f"Δ≤2 vs {ref}", "Δ≤2.5"]
    head += ["all times ≤2", "≤2.5"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, r in rows.items():
        cells = [name, r["code"], f(r.get("steps")), f(r.get("dt"), 4)]
        cells += [f(r.get("courant_max"), 2), f(r.get("cpu_s"), 0)]
        cells += [f"{f(r['spike'][i])} / {f(r['bubble'][i])}" for i in range(len(TAUS))]
        cells += [f(r.get("d2")), f(r.get("d25")), f(r.get("a2"), 4), f(r.get("a25"), 4)]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--stored-dir", type=Path, default=STORED_DIR, help="stored interFoam runs (tips_all.csv)"
    )
    ap.add_argument("--stored", nargs="*", default=["r100_dt0.001"], metavar="COL")
    ap.add_argument("--case", action="append", default=[], metavar="NAME=DIR")
    ap.add_argument("--run", action="append", default=[], metavar="NAME=DIR")
    ap.add_argument("--ref", default="r100_dt0.001", help="source the differences are to")
    ap.add_argument("--md", type=Path)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    rows: dict[str, dict[str, Any]] = {}
    for col in a.stored:
        rows[col] = stored(a.stored_dir, col)
    for text in a.case:
        name, path = _pair(text, "--case")
        rows[name] = foam_case(path)
    for text in a.run:
        name, path = _pair(text, "--run")
        rows[name] = pfem2x_run(path)
    if a.ref not in rows:
        _fail(f"--ref {a.ref}: not among the sources ({', '.join(rows)})")
    for r in rows.values():
        differences(r, rows[a.ref])
    md = table(rows, a.ref)
    print(md, end="")
    if a.md:
        a.md.write_text(md)
    if a.json:
        out = {n: {k: v for k, v in r.items() if k != "_hist"} for n, r in rows.items()}
        a.json.write_text(json.dumps({"taus": TAUS, "ref": a.ref, "rows": out}, indent=1))


if __name__ == "__main__":
    main()
