"""Rising bubble (Hysing et al. 2009, test cases 1 and 2): runs against the reference data.

Usage::

    python benchmarks/bubble_plot.py OUT.png LABEL=RUN_DIR [LABEL=RUN_DIR ...]
    python benchmarks/bubble_plot.py --study STUDY_DIR OUT.png [LABEL=RUN_DIR ...]

The first form draws four panels: the centroid height, the rise velocity and the
circularity against t (the ``diagnostics.csv`` columns ``t``, ``centroid_y``,
``rise_velocity``, ``circularity`` of each ``pfem2x run rising-bubble`` folder) and the
bubble shapes at ``--time`` (default t = 3, the polylines of
``interface/interface_tTTTT.TTTTT.csv``, columns ``line, x, y``). The test case is the
runs' ``params.case`` (their ``scene.toml``). Reference: the time series and the shape at
t = 3 of the group MooNMD (``docs/data/rising-bubble/moonmd/``, dashed black) and, as
stars, the paper's values (``docs/data/rising-bubble/hysing2009.csv``: TP2D for test
case 1, MooNMD for test case 2). It prints a markdown table: per run, the largest
differences to the MooNMD series over 0 <= t <= 3 (the metrics ``*_curve_error``, against
the package's copy of the series, ``pfem2x.cases.curve_errors``) and the distance between the run's
shape at ``--time`` and MooNMD's (the largest distance of a point of either curve to the
other, the Hausdorff distance; and its mean over the run's vertices).

The second form draws errors of a ``pfem2x study`` (``STUDY_DIR/study.json``; by default
the three relative errors of ``rising-bubble``, else ``--metric NAME[:TARGET]`` per panel)
against the CPU seconds of the time stepping: one curve per value of the varied keys other
than the Courant number, each point labelled with its Courant number, the runs
``LABEL=RUN_DIR`` (e.g. the scene's own small steps) as reference points and, per panel,
the Pareto front of all the points.

``LABEL=RUN_DIR`` is split at its last ``=`` (a label may contain ``=``). A missing or
unreadable file is one ``error:`` line on stderr and exit code 2, with nothing written.
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tomllib
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pfem2x.cases import BUBBLE_SERIES, curve_errors, moonmd_series  # noqa: E402
from pfem2x.study.rows import pareto_front  # noqa: E402

#: The reference values with their times (TP2D and MooNMD).
REFERENCE = Path(__file__).resolve().parents[1] / "docs/data/rising-bubble/hysing2009.csv"
#: MooNMD's time series ``c{case}g3l4.txt`` and shapes at t = 3 ``c{case}g3l4s.txt``.
MOONMD = REFERENCE.parent / "moonmd"
#: The group whose values are the stars, by test case.
STAR_GROUP = {1: "TP2D", 2: "MooNMD"}

#: (metric of ``summary.json``, target at h = 1/40): the default panels of ``--study``.
ERRORS = (
    ("centroid_y_final_rel_error", 0.01),
    ("rise_velocity_max_rel_error", 0.02),
    ("circularity_min_rel_error", 0.01),
)


def read_reference(
    path: Path, case: int = 1, group: str = "TP2D"
) -> dict[str, tuple[float, float]]:
    """Read one group's reference values of one test case.

    Parameters
    ----------
    path
        CSV with columns ``case, group, quantity, value, time``.
    case
        Hysing's test case.
    group
        The benchmark group (``TP2D``, ``MooNMD``).

    Returns
    -------
    dict
        ``quantity -> (time, value)``.
    """
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if int(r["case"]) == case and r["group"] == group]
    if not rows:
        raise ValueError(f"{path}: no values of group {group} for test case {case}")
    return {r["quantity"]: (float(r["time"]), float(r["value"])) for r in rows}


def read_series(folder: Path, case: int) -> dict[str, np.ndarray]:
    """Read MooNMD's time series of a test case (``c{case}g3l4.txt``).

    Columns of the file: t, 0 (unused), circularity, centroid height, rise velocity.

    Returns
    -------
    dict
        ``t``, ``circularity``, ``centroid_y``, ``rise_velocity``.
    """
    d = np.loadtxt(folder / f"c{case}g3l4.txt", ndmin=2)
    return {"t": d[:, 0], "circularity": d[:, 2], "centroid_y": d[:, 3], "rise_velocity": d[:, 4]}


def read_shape(folder: Path, case: int) -> np.ndarray:
    """MooNMD's bubble outline at t = 3 (``c{case}g3l4s.txt``, ``(n, 2)`` points x, y)."""
    return np.loadtxt(folder / f"c{case}g3l4s.txt", ndmin=2)


def point_polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance of each of ``points`` ``(n, 2)`` to the polyline ``line`` ``(m, 2)``."""
    a, b = line[:-1], line[1:]
    ab = b - a
    len2 = np.maximum((ab**2).sum(axis=1), 1e-300)
    s = ((points[:, None, :] - a[None]) * ab[None]).sum(axis=2) / len2[None]
    foot = a[None] + np.clip(s, 0.0, 1.0)[:, :, None] * ab[None]
    return np.sqrt(((points[:, None, :] - foot) ** 2).sum(axis=2)).min(axis=1)


def shape_distance(polys: list[np.ndarray], ref: np.ndarray) -> tuple[float, float]:
    """Hausdorff distance between the polylines ``polys`` and ``ref``, and the mean distance
    of the polylines' vertices to ``ref``."""
    pts = np.vstack(polys)
    d_run = point_polyline_distance(pts, ref)
    lines = [p if len(p) > 1 else np.vstack([p, p]) for p in polys]  # a lone point: itself
    d_ref = np.min([point_polyline_distance(ref, p) for p in lines], axis=0)
    return float(max(d_run.max(), d_ref.max())), float(d_run.mean())


def run_case(path: Path) -> int:
    """The test case of a run folder (``params.case`` of its ``scene.toml``; 1 without)."""
    scene = path / "scene.toml"
    if not scene.exists():
        return 1
    with open(scene, "rb") as f:
        return int(tomllib.load(f).get("params", {}).get("case", 1))


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


def _inset(ax: Any, t0: float, t1: float, pos: list[float], v: float) -> None:
    """Zoom of the panel ``ax`` to ``t0 <= t <= t1`` (every line, and the value ``v``)."""
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


def plot_runs(
    out: str, runs: list[str], time: float, reference: Path, series: Path = MOONMD
) -> list[dict[str, Any]]:
    """Draw the four-panel figure of the runs ``LABEL=RUN_DIR`` into ``out``.

    Parameters
    ----------
    out
        PNG file written.
    runs
        ``LABEL=RUN_DIR`` of runs of the scene ``rising-bubble``, all of one test case.
    time
        Time of the bubble shapes (an interface file of that time must exist).
    reference
        CSV of the reference values (:func:`read_reference`).
    series
        Folder of MooNMD's time series and shapes (:func:`read_series`, :func:`read_shape`).

    Returns
    -------
    list of dict
        Per run: ``label``, the largest differences to MooNMD's series (``centroid_y``,
        ``rise_velocity``, ``circularity``) and the shape distances ``shape_hausdorff``,
        ``shape_mean`` at ``time``.
    """
    specs = [split_spec(spec) for spec in runs]
    cases = {run_case(path) for _, path in specs}
    if len(cases) != 1:
        raise ValueError(f"the runs mix Hysing's test cases {sorted(cases)}")
    case = cases.pop()
    group = STAR_GROUP.get(case, "MooNMD")
    ref = read_reference(reference, case, group)
    moon, moon_shape = read_series(series, case), read_shape(series, case)
    packaged = moonmd_series(case)  # the metrics' copy (``*_curve_error``)
    if packaged is None:
        raise ValueError(f"no MooNMD series of test case {case} in the package")
    fig, axes = plt.subplots(2, 2, figsize=(9.5, 7.6), dpi=90)
    (a_y, a_u), (a_c, a_s) = axes
    panels = (
        (a_y, "centroid_y", "centroid height y_c", "centroid_y_final"),
        (a_u, "rise_velocity", "rise velocity u_c", "rise_velocity_max"),
        (a_c, "circularity", "circularity", "circularity_min"),
    )
    shown = moon["t"] <= 3.0 + 1e-9  # the benchmark's interval (case 2's series goes on)
    for ax, col, _, _ in panels:
        ax.plot(moon["t"][shown], moon[col][shown], "k--", lw=1.0, label="MooNMD")
    fname = f"interface_t{time:010.5f}.csv"
    rows: list[dict[str, Any]] = []
    for k, (label, path) in enumerate(specs):
        s = json.loads((path / "summary.json").read_text())
        if s.get("status") != "ok":
            label += f" ({s.get('status')})"
        d = np.genfromtxt(path / "diagnostics.csv", delimiter=",", names=True)
        color = None
        for ax, col, _, _ in panels:
            (line,) = ax.plot(d["t"], d[col], "-", lw=1.2, color=color, label=label)
            color = line.get_color()
        if k == 0:
            for poly in read_interface(path / "interface" / "interface_t0000.00000.csv"):
                a_s.plot(*poly.T, ":", color="0.5", lw=1)
            a_s.plot([], [], ":", color="0.5", label="t = 0")
        polys = read_interface(path / "interface" / fname)
        for i, poly in enumerate(polys):
            a_s.plot(*poly.T, "-", color=color, lw=1.2, label=label if i == 0 else None)
        vals = {k: d[k] for k in BUBBLE_SERIES}
        errs = curve_errors(d["t"], vals, packaged)
        row: dict[str, Any] = {"label": label}
        row.update({k.removesuffix("_curve_error"): v for k, v in errs.items()})
        if abs(time - 3.0) < 1e-9 and polys:
            row["shape_hausdorff"], row["shape_mean"] = shape_distance(polys, moon_shape)
        rows.append(row)
    if abs(time - 3.0) < 1e-9:
        a_s.plot(*moon_shape.T, "k--", lw=1.0, label="MooNMD")
    zooms = {  # around the reference values: (t range, inset position in the panel)
        a_y: ((2.85, 3.0), [0.55, 0.08, 0.42, 0.42]),
        a_u: ((0.6, 1.3) if case == 1 else (0.5, 1.0), [0.5, 0.08, 0.47, 0.4]),
    }
    for ax, _, ylabel, key in panels:
        t, v = ref[key]
        (star,) = ax.plot([t], [v], "k*", ms=11, zorder=5, label=f"{group}: {key}")
        ax.set(xlabel="t", ylabel=ylabel)
        ax.grid(alpha=0.3)
        if ax in zooms:  # the runs' legend in the other panels
            ax.legend(handles=[star, ax.get_lines()[0]], fontsize=7, loc="upper left")
            _inset(ax, *zooms[ax][0], zooms[ax][1], v)
        else:
            ax.legend(fontsize=7)
    t3, y3 = ref["centroid_y_final"]
    a_s.plot([0.5], [y3], "k*", ms=11, label=f"{group}: y_c({t3:g})")
    a_s.set(xlabel="x", ylabel="y", title=f"interface at t = {time:g}", aspect="equal")
    a_s.set_xlim(0.0, 1.0)
    a_s.set_ylim(0.4, 1.45)
    a_s.grid(alpha=0.3)
    a_s.legend(fontsize=7, loc="lower left")
    fig.suptitle(
        f"rising bubble, Hysing et al. (2009) test case {case}; dashed: MooNMD's series and "
        f"shape, stars: {group}'s values",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out)
    return rows


def markdown_rows(rows: list[dict[str, Any]]) -> str:
    """The table of :func:`plot_runs`' differences to MooNMD."""
    lines = [
        "| run | max \\|Δy_c\\| | max \\|Δu_c\\| | max \\|Δcircularity\\| "
        "| outline at t = 3: Hausdorff | mean |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        shape = [f"{r[k]:.4f}" if k in r else "" for k in ("shape_hausdorff", "shape_mean")]
        lines.append(
            f"| {r['label']} | {r['centroid_y']:.4f} | {r['rise_velocity']:.4f} "
            f"| {r['circularity']:.4f} | {shape[0]} | {shape[1]} |"
        )
    return "\n".join(lines) + "\n"


def read_study(folder: Path) -> tuple[list[str], list[dict[str, Any]]]:
    """Read ``folder/study.json``: the varied keys and the rows (one per variant)."""
    data = json.loads((folder / "study.json").read_text())
    return list(data["keys"]), list(data["rows"])


def _num(row: dict[str, Any], key: str) -> float:
    """``row[key]`` as a float (NaN if missing, empty or not a number)."""
    try:
        return float(row.get(key))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")


def parse_metric(spec: str) -> tuple[str, float | None]:
    """Split ``NAME[:TARGET]`` (TARGET a fraction, e.g. 0.01) into the name and target."""
    name, _, target = spec.partition(":")
    return name, float(target) if target else None


def plot_study(
    out: str,
    folder: Path,
    runs: list[str],
    metrics: list[tuple[str, float | None]],
    title: str = "",
) -> None:
    """Draw the errors of a study against the CPU seconds of its runs into ``out``.

    One panel per metric (its absolute value in %); one curve per value of the varied keys
    other than ``time.courant`` / ``time.dt`` (markers by frame), each point labelled with
    its Courant number; the runs ``LABEL=RUN_DIR`` as black reference points; the Pareto
    front of all the points of the panel (dashed).

    Parameters
    ----------
    out
        PNG file written.
    folder
        A ``pfem2x study`` folder (its ``study.json``).
    runs
        ``LABEL=RUN_DIR`` of runs drawn as reference points.
    metrics
        ``(metric, target)`` per panel; the target (a fraction) is drawn as a dotted line.
    title
        Figure title.
    """
    keys, rows = read_study(folder)
    others = [k for k in keys if k not in ("time.courant", "time.dt")]
    groups: dict[tuple[str, ...], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault(tuple(json.dumps(r.get(k)).strip('"') for k in others), []).append(r)
    iframe = others.index("method.frame") if "method.frame" in others else None

    def _rest(values: tuple[str, ...]) -> tuple[str, ...]:
        return tuple(v for i, v in enumerate(values) if i != iframe)

    rest = sorted({_rest(v) for v in groups})  # the line style: the keys other than the frame
    names = {"lagrangian": "PFEM-2", "eulerian": "Eulerian", "characteristic": "char. Galerkin"}
    markers = {"lagrangian": "o", "eulerian": "s", "characteristic": "^"}
    styles = ["-", "--", "-.", ":"]
    size = (4.2 * len(metrics) + 0.5, 4.3) if len(metrics) > 1 else (6.5, 5.2)
    fig, axes = plt.subplots(1, len(metrics), figsize=size, dpi=90)
    axes = np.atleast_1d(axes)
    for ax, (metric, target) in zip(axes, metrics, strict=True):
        pts: list[tuple[float, float]] = []
        scale, unit = (100.0, " in %") if "rel_error" in metric else (1.0, "")
        for values, rs in sorted(groups.items()):
            rs = sorted(rs, key=lambda r: _num(r, "time.courant"))
            cpu = np.array([_num(r, "cpu_seconds") for r in rs])
            err = np.abs([_num(r, metric) for r in rs]) * scale
            frame = rs[0].get("frame", "")
            label = ", ".join(
                names.get(v, v) if k == "method.frame" else f"{k.split('.')[-1]} {v}"
                for k, v in zip(others, values, strict=True)
            )
            ok = np.array([r.get("status") == "ok" for r in rs]) & np.isfinite(cpu * err)
            ax.plot(
                cpu[ok],
                err[ok],
                markers.get(frame, "D") + styles[rest.index(_rest(values)) % len(styles)],
                label=label,
            )
            for r, x, y in zip(np.array(rs)[ok], cpu[ok], err[ok], strict=True):
                pts.append((float(x), float(y)))
                ax.annotate(
                    f"{r.get('time.courant', '')}", (x, y), fontsize=6, xytext=(3, 2),
                    textcoords="offset points",
                )  # fmt: skip
        for i, spec in enumerate(runs):
            label, path = split_spec(spec)
            s = json.loads((path / "summary.json").read_text())
            pts.append((float(s["cpu_seconds"]), abs(s["metrics"][metric]) * scale))
            ax.plot(*pts[-1], "PXDv"[i % 4], color="k", ms=8, label=label)
        if pts:
            xs = [x for x, _ in pts]
            front = sorted(pts[i] for i in pareto_front(pts))
            ax.plot(*np.array(front).T, "k--", drawstyle="steps-post", lw=0.8, label="Pareto")
            ax.set_xlim(0.5 * min(xs), 2 * max(xs))
        name = metric.replace("_rel_error", "")
        if target is not None:
            ax.axhline(target * scale, color="0.4", lw=0.8, ls=":", label="target")
            name += f" (target {target * scale:g}{unit.replace(' in', '')})"
        ax.set(xscale="log", yscale="log", xlabel="CPU s (time stepping)")
        ax.set_title(name, fontsize=10)
        ax.set_ylabel(f"|{metric}|{unit}")
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0].get_legend_handles_labels()
    nleg = max(1, min(len(labels), 4 if len(metrics) > 1 else 2))
    fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=nleg)
    fig.suptitle(f"{title}; numbers: Courant".lstrip("; "), fontsize=9)
    nrow = -(-len(labels) // nleg)
    fig.tight_layout(rect=(0, 0.035 * nrow * (4.3 / fig.get_figheight()) + 0.02, 1, 1))
    fig.savefig(out)


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and draw the figure; return the exit code."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("out", help="PNG file written")
    p.add_argument("runs", nargs="*", metavar="LABEL=RUN_DIR", help="run folders")
    p.add_argument("--time", type=float, default=3.0, help="time of the shapes (default 3)")
    p.add_argument("--reference", type=Path, default=REFERENCE, help="reference values (CSV)")
    p.add_argument("--study", type=Path, help="a study folder: draw its errors against CPU s")
    p.add_argument(
        "--metric",
        action="append",
        metavar="NAME[:TARGET]",
        help="with --study: a panel per metric (default: the bubble's three relative errors "
        "with the h = 1/40 targets 0.01, 0.02, 0.01)",
    )
    p.add_argument("--title", default="", help="with --study: the figure's title")
    a = p.parse_args(argv)
    try:
        if a.study is not None:
            metrics = [parse_metric(m) for m in a.metric] if a.metric else list(ERRORS)
            plot_study(a.out, a.study, a.runs, metrics, a.title)
        elif not a.runs:
            p.error("at least one LABEL=RUN_DIR")
        else:
            print(markdown_rows(plot_runs(a.out, a.runs, a.time, a.reference)), end="")
    except (OSError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
