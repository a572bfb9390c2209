"""Rising bubble (Hysing et al. 2009, test case 1): runs against the TP2D reference values.

Usage::

    python benchmarks/bubble_plot.py OUT.png LABEL=RUN_DIR [LABEL=RUN_DIR ...]
    python benchmarks/bubble_plot.py --study STUDY_DIR OUT.png [LABEL=RUN_DIR ...]

The first form draws four panels: the centroid height, the rise velocity and the
circularity against t (the ``diagnostics.csv`` columns ``t``, ``centroid_y``,
``rise_velocity``, ``circularity`` of each ``pfem2x run rising-bubble`` folder) and the
bubble shapes at ``--time`` (default t = 3, the polylines of
``interface/interface_tTTTT.TTTTT.csv``, columns ``line, x, y``). The reference group TP2D
of the paper gives three values, not curves (``docs/data/rising-bubble/hysing2009.csv``:
the centroid at t = 3, the maximum rise velocity and its time, the minimum circularity and
its time); they are marked as points. No reference curve or shape is stored in the
repository.

The second form draws the three relative errors of a ``pfem2x study rising-bubble``
(``STUDY_DIR/study.csv``) against the CPU seconds of the time stepping, one marker per
frame and damping, labelled with the Courant number, with the runs ``LABEL=RUN_DIR``
(e.g. the scene's own small steps) as reference points and, per error, the Pareto front of
all the points (error against CPU seconds).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pfem2x.study.rows import pareto_front  # noqa: E402

#: The reference values with their times (TP2D, test case 1).
REFERENCE = Path(__file__).resolve().parents[1] / "docs/data/rising-bubble/hysing2009.csv"

#: (metric of ``summary.json``, axis label, tolerance at h = 1/40) of the study panels.
ERRORS = (
    ("centroid_y_final_rel_error", "centroid y_c(3)", 0.01),
    ("rise_velocity_max_rel_error", "max rise velocity", 0.02),
    ("circularity_min_rel_error", "min circularity", 0.01),
)


def read_reference(path: Path, case: int = 1) -> dict[str, tuple[float, float]]:
    """Read the reference values of one test case.

    Parameters
    ----------
    path
        CSV with columns ``case, group, quantity, value, time``.
    case
        Hysing's test case.

    Returns
    -------
    dict
        ``quantity -> (time, value)``.
    """
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if int(r["case"]) == case]
    return {r["quantity"]: (float(r["time"]), float(r["value"])) for r in rows}


def read_interface(path: Path) -> list[np.ndarray]:
    """Read the interface polylines of a run.

    Parameters
    ----------
    path
        CSV with columns ``line, x, y`` (one row per vertex).

    Returns
    -------
    list of ndarray
        One ``(n, 2)`` array of vertices per polyline.
    """
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.size == 0:
        return []
    lines = data[:, 0].astype(int)
    cuts = np.flatnonzero(np.diff(lines)) + 1
    return [p[:, 1:] for p in np.split(data, cuts)]


def split_spec(spec: str) -> tuple[str, Path]:
    """Split ``LABEL=RUN_DIR`` at its last ``=`` into the label and the folder."""
    if "=" not in spec:
        raise ValueError(f"expected LABEL=RUN_DIR, got {spec!r}")
    label, path = spec.rsplit("=", 1)
    return label, Path(path)


def plot_runs(out: str, runs: list[str], time: float, reference: Path) -> None:
    """Draw the four-panel figure of the runs ``LABEL=RUN_DIR`` into ``out``.

    Parameters
    ----------
    out
        PNG file written.
    runs
        ``LABEL=RUN_DIR`` of runs of the scene ``rising-bubble``.
    time
        Time of the bubble shapes (an interface file of that time must exist).
    reference
        CSV of the reference values (:func:`read_reference`).
    """
    ref = read_reference(reference)
    fig, axes = plt.subplots(2, 2, figsize=(9.5, 7.6), dpi=90)
    (a_y, a_u), (a_c, a_s) = axes
    panels = (
        (a_y, "centroid_y", "centroid height y_c", "centroid_y_final"),
        (a_u, "rise_velocity", "rise velocity u_c", "rise_velocity_max"),
        (a_c, "circularity", "circularity", "circularity_min"),
    )
    ref_labels = {
        "centroid_y_final": "TP2D: y_c(3)",
        "rise_velocity_max": "TP2D: max u_c",
        "circularity_min": "TP2D: min circularity",
    }
    fname = f"interface_t{time:010.5f}.csv"
    first = True
    for spec in runs:
        label, path = split_spec(spec)
        s = json.loads((path / "summary.json").read_text())
        if s.get("status") != "ok":
            label += f" ({s.get('status')})"
        d = np.genfromtxt(path / "diagnostics.csv", delimiter=",", names=True)
        color = None
        for ax, col, _, _ in panels:
            (line,) = ax.plot(d["t"], d[col], "-", lw=1.2, color=color, label=label)
            color = line.get_color()
        if first:
            for poly in read_interface(path / "interface" / "interface_t0000.00000.csv"):
                a_s.plot(*poly.T, ":", color="0.5", lw=1)
            a_s.plot([], [], ":", color="0.5", label="t = 0")
            first = False
        for i, poly in enumerate(read_interface(path / "interface" / fname)):
            a_s.plot(*poly.T, "-", color=color, lw=1.2, label=label if i == 0 else None)
    # zooms around the reference values: (t range, inset position in the panel)
    zooms = {
        a_y: ((2.85, 3.0), [0.55, 0.08, 0.42, 0.42]),
        a_u: ((0.6, 1.3), [0.5, 0.08, 0.47, 0.4]),
    }
    for ax, _, ylabel, key in panels:
        t, v = ref[key]
        (star,) = ax.plot([t], [v], "k*", ms=11, zorder=5, label=ref_labels[key])
        ax.set(xlabel="t", ylabel=ylabel)
        ax.grid(alpha=0.3)
        if ax in zooms:  # the runs' legend in the other panels
            ax.legend(handles=[star], fontsize=7, loc="upper left")
        else:
            ax.legend(fontsize=7)
        if ax in zooms:
            (t0, t1), pos = zooms[ax]
            ins = ax.inset_axes(pos)
            lo, hi = v, v
            for line in ax.get_lines():
                x, y = (np.asarray(c, dtype=float) for c in line.get_data())
                sel = (x >= t0) & (x <= t1)
                if sel.any():
                    ins.plot(
                        x[sel],
                        y[sel],
                        line.get_linestyle(),
                        marker=line.get_marker(),
                        color=line.get_color(),
                        lw=1,
                        ms=line.get_markersize() * 0.7,
                    )
                    lo, hi = min(lo, y[sel].min()), max(hi, y[sel].max())
            pad = 0.05 * (hi - lo)
            ins.set_xlim(t0, t1)
            ins.set_ylim(lo - pad, hi + pad)
            ins.tick_params(labelsize=6)
            ins.grid(alpha=0.3)
    t3, y3 = ref["centroid_y_final"]
    a_s.plot([0.5], [y3], "k*", ms=11, label=f"TP2D: y_c({t3:g})")
    a_s.set(xlabel="x", ylabel="y", title=f"interface at t = {time:g}", aspect="equal")
    a_s.set_xlim(0.0, 1.0)
    a_s.set_ylim(0.4, 1.4)
    a_s.grid(alpha=0.3)
    a_s.legend(fontsize=7, loc="lower left")
    fig.suptitle(
        "rising bubble, Hysing et al. (2009) test case 1; stars: TP2D reference values "
        "(no reference curves stored)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out)


def read_study(folder: Path) -> list[dict[str, str]]:
    """Read the rows of ``folder/study.csv`` (one per variant)."""
    with open(folder / "study.csv", newline="") as f:
        return list(csv.DictReader(f))


def _num(row: dict[str, str], key: str) -> float:
    """``row[key]`` as a float (NaN if missing or empty)."""
    try:
        return float(row.get(key) or "nan")
    except ValueError:
        return float("nan")


def plot_study(out: str, folder: Path, runs: list[str]) -> None:
    """Draw the three relative errors of a study against CPU seconds into ``out``.

    Parameters
    ----------
    out
        PNG file written.
    folder
        A ``pfem2x study rising-bubble`` folder varying ``time.courant``,
        ``method.frame`` and ``flow.capillary_damping``.
    runs
        ``LABEL=RUN_DIR`` of runs drawn as reference points (black markers).
    """
    rows = read_study(folder)
    fig, axes = plt.subplots(1, 3, figsize=(12.5, 4.2), dpi=90)
    groups: dict[tuple[str, str], list[dict[str, str]]] = {}
    for r in rows:
        key = (r.get("method.frame", "").strip('"'), r.get("flow.capillary_damping", "").strip('"'))
        groups.setdefault(key, []).append(r)
    names = {"lagrangian": "PFEM-2", "eulerian": "level set"}
    markers = {"lagrangian": "o", "eulerian": "s"}
    styles = {"surface": "-", "normal": "--"}
    for ax, (metric, title, tol) in zip(axes, ERRORS, strict=True):
        pts: list[tuple[float, float]] = []
        for (frame, damping), rs in sorted(groups.items()):
            rs = sorted(rs, key=lambda r: _num(r, "time.courant"))
            cpu = np.array([_num(r, "cpu_seconds") for r in rs])
            err = np.abs([_num(r, metric) for r in rs]) * 100
            ax.plot(
                cpu,
                err,
                markers.get(frame, "^") + styles.get(damping, ":"),
                label=f"{names.get(frame, frame)}, {damping}",
            )
            for r, x, y in zip(rs, cpu, err, strict=True):
                if np.isfinite(x) and np.isfinite(y) and r.get("status") == "ok":
                    pts.append((float(x), float(y)))
                    ax.annotate(
                        r.get("time.courant", ""), (x, y), fontsize=6, xytext=(3, 2),
                        textcoords="offset points",
                    )  # fmt: skip
        for i, spec in enumerate(runs):
            label, path = split_spec(spec)
            s = json.loads((path / "summary.json").read_text())
            pts.append((float(s["cpu_seconds"]), abs(s["metrics"][metric]) * 100))
            ax.plot(
                *pts[-1],
                "kP^v"[i % 4],
                ms=8,
                label=label,
            )
        xs = [x for x, _ in pts]
        front = sorted(pts[i] for i in pareto_front(pts))
        ax.plot(*np.array(front).T, "k--", drawstyle="steps-post", lw=0.8, label="Pareto front")
        ax.set_xlim(0.5 * min(xs), 2 * max(xs))
        ax.axhline(tol * 100, color="0.4", lw=0.8, ls=":", label=f"h = 1/40 target {tol:.0%}")
        ax.set(xscale="log", yscale="log", xlabel="CPU s (time stepping)", title=title)
        ax.set_ylabel("|relative error| in % against TP2D")
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    fig.suptitle(
        "rising bubble case 1, h = 1/40, flow.capillary_increment = true; numbers: Courant",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out)


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and draw the figure; return the exit code."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="PNG file written")
    p.add_argument("runs", nargs="*", metavar="LABEL=RUN_DIR", help="run folders")
    p.add_argument("--time", type=float, default=3.0, help="time of the shapes (default 3)")
    p.add_argument("--reference", type=Path, default=REFERENCE, help="reference values (CSV)")
    p.add_argument("--study", type=Path, help="a study folder: draw its errors against CPU s")
    a = p.parse_args(argv)
    try:
        if a.study is not None:
            plot_study(a.out, a.study, a.runs)
        elif not a.runs:
            p.error("at least one LABEL=RUN_DIR")
        else:
            plot_runs(a.out, a.runs, a.time, a.reference)
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
