"""Study report: ``study.csv``, ``study.json`` and ``study.md``."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pfem2x.io import atomic_write_text

#: Columns every row has (besides the varied keys, first, and the metrics).
BASE_COLUMNS = (
    "run",
    "frame",
    "status",
    "exit_code",
    "steps",
    "dt",
    "courant_max",
    "wall_seconds",
    "cpu_seconds",
    "setup_seconds",
    "process_wall_seconds",
    "process_cpu_seconds",
    "peak_rss_mb",
    "resumed",
)


def _columns(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> tuple[list[str], list[str]]:
    metrics: list[str] = []
    for r in rows:
        metrics += [k for k in r["metrics"] if k not in metrics]
    return [*keys, *BASE_COLUMNS, "pareto"], metrics


def _cell(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, list | dict):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    return v


def _flat(row: dict[str, Any]) -> dict[str, Any]:
    out = {k: v for k, v in row.items() if k != "metrics"}
    out.update(row["metrics"])
    return out


def write_tables(out: Path, info: dict[str, Any], rows: list[dict[str, Any]]) -> None:
    """Write ``study.csv`` and ``study.json``."""
    cols, metrics = _columns(rows, info["keys"])
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow([*cols, *metrics, "message"])
    for r in rows:
        f = _flat(r)
        w.writerow([_cell(f.get(c)) for c in [*cols, *metrics, "message"]])
    atomic_write_text(out / "study.csv", buf.getvalue())
    data = dict(info, rows=[_flat(r) for r in rows])
    atomic_write_text(out / "study.json", json.dumps(data, indent=2) + "\n")


def fmt(v: Any) -> str:
    """A table cell of ``study.md`` (and a plot label): floats to 4 digits."""
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else ""
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return json.dumps(v)
    return str(v)


def fmt_value(v: Any) -> str:
    """A varied key's value in a table or plot label: booleans as TOML writes them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    return fmt(v)


def write_markdown(
    out: Path, info: dict[str, Any], rows: list[dict[str, Any]], plots: list[str]
) -> None:
    """Write ``study.md``: the table, failures and the plots."""
    metric = info["metric"]
    keys = info["keys"]
    lines = [f"# Study of `{info['scene']}`", ""]
    if info["variant"]:
        lines.append(f"- variant: `{info['variant']}`")
    for s in info["sets"]:
        lines.append(f"- `--set {s}`")
    lines += [f"- `--vary {a}`" for a in info["axes"]]
    lines += [f"- metric: `{metric}`" if metric else "- metric: none", ""]
    head = [
        *keys,
        "frame",
        "status",
        metric or "metric",
        "wall s",
        "CPU s",
        "steps",
        "Δt",
        "Courant max",
        "peak MB",
        "Pareto",
    ]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [fmt_value(r.get(k)) for k in keys] + [
            r["frame"],
            r["status"],
            fmt(r["metrics"].get(metric)) if metric else "",
            fmt(r["wall_seconds"]),
            fmt(r["cpu_seconds"]),
            fmt(r["steps"]),
            fmt(r["dt"]),
            fmt(r["courant_max"]),
            fmt(r["peak_rss_mb"]),
            "★" if r.get("pareto") else "",
        ]
        lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    bad = [r for r in rows if r["status"] != "ok"]
    if bad:
        lines += ["", "## Failed or diverged", ""]
        lines += [f"- `{r['run']}` ({r['status']}): {r['message']}" for r in bad]
    lines += [
        "",
        "Wall and CPU seconds are the run's time stepping (summary.json); the process columns "
        "of study.csv include start-up, mesh and JIT. Pareto: no other ok variant is both "
        "faster and more accurate.",
    ]
    if plots:
        lines += [""] + [f"![{p}]({p})" for p in plots]
    atomic_write_text(out / "study.md", "\n".join(lines) + "\n")
