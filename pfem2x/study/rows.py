"""Study rows: one table row per variant, the metric plotted and the Pareto front."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from pfem2x.study.plan import Variant, is_number

#: ``--metric`` default: the first of these present, else the first numeric
#: metric whose name contains "error", else the first numeric metric.
DEFAULT_METRICS = ("l2_error_time_avg", "l2_error_final", "symmetric_difference", "tip_error")
#: A variant folder whose summary has one of these statuses is not run again.
DONE_STATUSES = ("ok", "diverged")


def make_row(
    v: Variant, summary: dict[str, Any] | None, rec: dict[str, Any], resumed: bool
) -> dict:
    """One table row from the variant, its summary (if any) and its process record."""
    row: dict[str, Any] = dict(v.values)
    code = rec.get("exit_code")
    if summary is not None and summary.get("status") in DONE_STATUSES and code in (0, 3, None):
        status = summary["status"]
        message = summary.get("message", "") if status != "ok" else ""
        if code is None:
            code = 0 if status == "ok" else 3
    else:
        status = "failed"
        summary = None
        message = rec.get("message", "") or f"exit code {code} and no summary.json"
    s = summary or {}
    row.update(
        run=v.slug,
        frame=s.get("frame", v.frame),
        status=status,
        exit_code=code,
        steps=s.get("steps"),
        dt=s.get("dt"),
        courant_max=s.get("courant_max"),
        wall_seconds=s.get("wall_seconds"),
        cpu_seconds=s.get("cpu_seconds"),
        setup_seconds=s.get("setup_seconds"),
        process_wall_seconds=rec.get("process_wall_seconds"),
        process_cpu_seconds=rec.get("process_cpu_seconds"),
        peak_rss_mb=rec.get("peak_rss_mb"),
        resumed=resumed,
    )
    metrics = s.get("metrics") or {}
    row["metrics"] = {
        k: float(x)
        for k, x in metrics.items()
        if is_number(x) and k not in row and k not in ("metrics", "message")
    }
    row["message"] = message
    return row


def choose_metric(rows: Sequence[dict[str, Any]], wanted: str | None = None) -> str | None:
    """The metric to plot: ``wanted`` if given, else the default order (see DEFAULT_METRICS)."""
    names: list[str] = []
    for r in rows:
        names += [k for k in r["metrics"] if k not in names]
    if wanted is not None:
        return wanted if wanted in names else None
    for name in DEFAULT_METRICS:
        if name in names:
            return name
    errors = [n for n in names if "error" in n]
    return (errors or names or [None])[0]


def pareto_front(points: Sequence[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated in (cost, error), both minimised, by cost."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def plot_value(row: dict[str, Any], metric: str | None) -> float | None:
    """``|metric|`` of an ok row with a finite value and wall time, else None."""
    if metric is None or row["status"] != "ok" or row.get("wall_seconds") is None:
        return None
    x = row["metrics"].get(metric)
    return abs(x) if x is not None and math.isfinite(x) else None
