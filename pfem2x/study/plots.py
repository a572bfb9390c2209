"""Study plots: ``error_vs_wall.png`` and ``error_vs_dt.png`` (matplotlib, imported on use)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pfem2x.study.report import fmt_value
from pfem2x.study.rows import pareto_front, plot_value

#: (row, |metric|) pairs of the plotted rows
Points = list[tuple[dict[str, Any], float]]


def _log_axes(ax: Any, xs: Sequence[float], ys: Sequence[float]) -> None:
    if xs and min(xs) > 0:
        ax.set_xscale("log")
    if ys and min(ys) > 0:
        ax.set_yscale("log")


def write_plots(out: Path, info: dict[str, Any], rows: list[dict[str, Any]]) -> list[str]:
    """Write ``error_vs_wall.png`` and ``error_vs_dt.png``; return the file names written."""
    metric = info["metric"]
    pts = [(r, plot_value(r, metric)) for r in rows]
    pts = [(r, y) for r, y in pts if y is not None]
    if not pts:
        return []
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    _plot_wall(plt, out / "error_vs_wall.png", info, pts)
    _plot_dt(plt, out / "error_vs_dt.png", info, pts)
    return ["error_vs_wall.png", "error_vs_dt.png"]


def _plot_wall(plt: Any, path: Path, info: dict[str, Any], pts: Points) -> None:
    """Error against wall time: one curve per frame, the Pareto front marked."""
    keys = info["keys"]
    fig, ax = plt.subplots(figsize=(7, 5))
    frames = list(dict.fromkeys(r["frame"] for r, _ in pts))
    for fr in frames:
        sel = [(r["wall_seconds"], y) for r, y in pts if r["frame"] == fr]
        ax.plot([p[0] for p in sel], [p[1] for p in sel], "o", label=fr, alpha=0.8)
    front = [pts[i] for i in pareto_front([(r["wall_seconds"], y) for r, y in pts])]
    fx, fy = [r["wall_seconds"] for r, _ in front], [y for _, y in front]
    ax.plot(fx, fy, "k--", drawstyle="steps-post", lw=1, label="Pareto front")
    ax.plot(fx, fy, "o", ms=12, mfc="none", mec="k")
    if len(pts) <= 16:
        for r, y in pts:
            text = "\n".join(f"{k.split('.')[-1]}={fmt_value(r[k])}" for k in keys)
            ax.annotate(text, (r["wall_seconds"], y), fontsize=6, xytext=(4, 4),
                        textcoords="offset points")  # fmt: skip
    _log_axes(ax, [r["wall_seconds"] for r, _ in pts], [y for _, y in pts])
    ax.set_xlabel("wall seconds (time stepping)")
    ax.set_ylabel(f"|{info['metric']}|")
    ax.set_title(f"{info['scene']}: error against wall time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_dt(plt: Any, path: Path, info: dict[str, Any], pts: Points) -> None:
    """Error against Δt and Courant: one curve per frame and other varied keys."""
    others = [k for k in info["keys"] if k not in ("time.dt", "time.courant", "method.frame")]
    groups: dict[str, list[tuple[dict, float]]] = {}
    for r, y in pts:
        label = " ".join([r["frame"]] + [f"{k.split('.')[-1]}={fmt_value(r[k])}" for k in others])
        groups.setdefault(label, []).append((r, y))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, xkey, xlabel in ((axes[0], "dt", "Δt"), (axes[1], "courant_max", "Courant max")):
        xs_all, ys_all = [], []
        for label, grp in groups.items():
            sel = sorted((r[xkey], y) for r, y in grp if r.get(xkey) is not None)
            ax.plot([p[0] for p in sel], [p[1] for p in sel], "o-", label=label)
            xs_all += [p[0] for p in sel]
            ys_all += [p[1] for p in sel]
        _log_axes(ax, xs_all, ys_all)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(f"|{info['metric']}|")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{info['scene']}: error against Δt and Courant number")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
