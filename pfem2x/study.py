"""Parameter studies: ``pfem2x study`` shows what accuracy costs in time.

A study runs the cartesian product of ``--vary KEY=V1,V2,...`` lists of a scene,
each variant in its own process (``python -m pfem2x run SCENE --set ... --out
DIR/variants/<slug> --quiet --overwrite``), and tabulates, per variant, the
varied keys, the scene's error metrics (every numeric scalar of the summary's
``metrics``), wall and CPU seconds, steps, the child's peak memory, status and
exit code in ``study.csv``, ``study.json`` and ``study.md``, with two plots:
error against wall time (one curve per frame, the Pareto front marked) and
error against Δt and against the Courant number.

The driver is serial and never imports DOLFINx or MPI; every variant is checked
with :func:`pfem2x.scene.load_scene` before anything runs or is written. It is
resumable: a variant whose folder holds a ``summary.json`` with status ``ok`` or
``diverged`` and the same resolved ``scene.toml`` is not run again.

Exit codes: 0 the study ran (failed or diverged variants are rows with their
status), 2 bad input (one ``error:`` line on stderr naming the key; nothing run
or written), 130 interrupted.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pfem2x.io import atomic_write_text
from pfem2x.output import check_default_out
from pfem2x.scene import Scene, SceneError, load_scene, parse_override

__all__ = [
    "DEFAULT_METRICS",
    "StudyError",
    "Variant",
    "add_study_parser",
    "pareto_front",
    "parse_vary",
    "plan_study",
    "run_study",
    "split_values",
    "study_main",
]

#: ``--metric`` default: the first of these present, else the first numeric
#: metric whose name contains "error", else the first numeric metric.
DEFAULT_METRICS = ("l2_error_time_avg", "l2_error_final", "symmetric_difference", "tip_error")
#: A variant folder whose summary has one of these statuses is not run again.
DONE_STATUSES = ("ok", "diverged")
#: Process measurements saved next to each variant's summary (for resumed rows).
RUN_RECORD = "study-run.json"
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
EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130


class StudyError(SceneError):
    """Bad study input; the message names the key or option."""


@dataclass
class Variant:
    """One point of the study's product.

    Attributes
    ----------
    slug:
        Folder name under ``DIR/variants``.
    texts:
        Varied key → value as given on the command line.
    values:
        Varied key → value parsed as TOML.
    overrides:
        The child's ``--set`` list (the study's ``--set`` then the varied keys).
    frame:
        The variant's ``method.frame``.
    resolved:
        The resolved scene text the child writes to ``scene.toml`` (resume check).
    """

    slug: str
    texts: dict[str, str]
    values: dict[str, Any]
    overrides: list[str]
    frame: str
    resolved: str

    def label(self) -> str:
        """``key=value`` pairs, for progress lines and plot labels."""
        return " ".join(f"{k}={v}" for k, v in self.texts.items())


@dataclass
class StudyResult:
    """What :func:`run_study` produced."""

    exit_code: int
    out_dir: Path
    rows: list[dict[str, Any]] = field(default_factory=list)
    metric: str | None = None
    ran: int = 0


# --------------------------------------------------------------------------
# Input
# --------------------------------------------------------------------------
def split_values(text: str) -> list[str]:
    """Split a value list on the commas at bracket depth 0 (outside TOML strings).

    ``"[50,200],[100,400]"`` → ``["[50,200]", "[100,400]"]``; items are stripped.

    Raises
    ------
    StudyError
        On unbalanced brackets or quotes.
    """
    items, cur, depth, quote = [], [], 0, ""
    for ch in text:
        if quote:
            cur.append(ch)
            if ch == quote:
                quote = ""
            continue
        if ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
            if depth < 0:
                raise StudyError(f"unbalanced {ch!r} in {text!r}")
        elif ch == "," and depth == 0:
            items.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    if quote or depth:
        raise StudyError(f"unclosed {'quote' if quote else 'bracket'} in {text!r}")
    items.append("".join(cur).strip())
    return items


def parse_vary(text: str) -> tuple[str, list[str], list[Any]]:
    """Parse ``--vary KEY=V1,V2,...`` into the key, value texts and TOML values.

    Raises
    ------
    StudyError
        Naming the key: no ``=``, bad key, empty list or item, unreadable or
        repeated value.
    """
    if "=" not in text:
        raise StudyError(f"--vary {text}: expected KEY=V1,V2,..., e.g. time.courant=1,2,4")
    key, _, vals = text.partition("=")
    key = key.strip()
    if not key or any(not p.strip() or p != p.strip() for p in key.split(".")):
        raise StudyError(f"--vary {text}: bad key {key!r}")
    if not vals.strip():
        raise StudyError(f"--vary {key}: empty value list (expected {key}=V1,V2,...)")
    try:
        texts = split_values(vals)
    except StudyError as exc:
        raise StudyError(f"--vary {key}: {exc}") from None
    values: list[Any] = []
    for i, v in enumerate(texts):
        if not v:
            raise StudyError(f"--vary {key}: value {i + 1} of {vals.strip()!r} is empty")
        try:
            _, value = parse_override(f"{key}={v}")
        except SceneError as exc:
            raise StudyError(str(exc).replace("--set ", "--vary ", 1)) from None
        if any(_same(value, u) for u in values):
            raise StudyError(f"--vary {key}: value {v} is given twice")
        values.append(value)
    return key, texts, values


def _same(a: Any, b: Any) -> bool:
    if _is_number(a) and _is_number(b):
        return a == b
    return type(a) is type(b) and a == b


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _slug_part(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.+-]+", "-", text).strip("-.") or "x"


def _make_slug(texts: dict[str, str]) -> str:
    slug = "_".join(f"{k}-{_slug_part(v)}" for k, v in texts.items())
    if len(slug) > 120:
        digest = hashlib.sha1(json.dumps(texts, sort_keys=True).encode()).hexdigest()[:10]
        slug = f"{slug[:100]}_{digest}"
    return slug


def plan_study(
    scene: str,
    vary: Sequence[str],
    sets: Sequence[str] = (),
    variant: str | None = None,
) -> tuple[Scene, list[Variant]]:
    """Parse the options and validate every variant (nothing is run or written).

    Parameters
    ----------
    scene:
        A scene file or built-in scene name.
    vary:
        ``KEY=V1,V2,...`` strings.
    sets:
        ``KEY=VALUE`` overrides common to every variant.
    variant:
        The scene's ``[variants.NAME]`` to apply first.

    Returns
    -------
    tuple
        The base scene (``sets`` and ``variant`` applied) and the variants in
        product order (the last ``--vary`` key varies fastest).

    Raises
    ------
    SceneError
        (or :class:`StudyError`) with a message naming the key.
    """
    if not vary:
        raise StudyError("--vary: give at least one KEY=V1,V2,...")
    base = load_scene(scene, list(sets), variant)
    set_keys = {".".join(parse_override(s)[0]) for s in sets}
    axes: list[tuple[str, list[str], list[Any]]] = []
    for text in vary:
        key, texts, values = parse_vary(text)
        if any(key == k for k, _, _ in axes):
            raise StudyError(f"--vary {key}: the key is varied twice")
        if key in set_keys:
            raise StudyError(f"--vary {key}: the key is also given with --set")
        parts = key.split(".")
        if parts[0] == "params" and len(parts) == 2 and parts[1] not in base.params:
            known = ", ".join(sorted(base.params)) or "none"
            raise StudyError(f"{key}: unknown parameter of scene {base.name} (has: {known})")
        if parts[0] == "variants":
            raise StudyError(f"--vary {key}: use --variant NAME for the scene's variants")
        axes.append((key, texts, values))
    variants: list[Variant] = []
    seen: set[str] = set()
    for combo in itertools.product(*(range(len(t)) for _, t, _ in axes)):
        texts = {k: t[i] for (k, t, _), i in zip(axes, combo, strict=True)}
        values = {k: v[i] for (k, _, v), i in zip(axes, combo, strict=True)}
        overrides = list(sets) + [f"{k}={v}" for k, v in texts.items()]
        label = ", ".join(f"{k}={v}" for k, v in texts.items())
        try:
            sc = load_scene(scene, overrides, variant)
        except SceneError as exc:
            raise StudyError(f"{exc} (study variant {label})") from None
        slug = _make_slug(texts)
        if slug in seen:  # e.g. values differing only in punctuation
            digest = hashlib.sha1(json.dumps(texts, sort_keys=True).encode()).hexdigest()[:10]
            slug = f"{slug[:100]}_{digest}"
        seen.add(slug)
        variants.append(Variant(slug, texts, values, overrides, sc.frame, sc.resolved_toml()))
    return base, variants


# --------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------
def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return data if isinstance(data, dict) else None


def _is_done(v: Variant, vdir: Path) -> dict[str, Any] | None:
    """The summary of a finished run of ``v`` in ``vdir`` (same resolved scene), else None."""
    summary = _read_json(vdir / "summary.json")
    if summary is None or summary.get("status") not in DONE_STATUSES:
        return None
    try:
        if (vdir / "scene.toml").read_text(encoding="utf-8") != v.resolved:
            return None  # run with other --set values or another scene version
    except (OSError, UnicodeDecodeError):
        return None
    return summary


def _last_line(path: Path) -> str:
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    for line in reversed(lines):
        if line.strip():
            return line.strip()[:500]
    return ""


class _Runner:
    """Runs children and kills the ones still running on interrupt."""

    def __init__(self, python: str, scene: str, variant: str | None, out: Path):
        self.python, self.scene, self.variant, self.out = python, scene, variant, out
        self.lock = threading.Lock()
        self.procs: dict[int, subprocess.Popen] = {}
        self.stopping = False
        self.env = dict(os.environ)
        # Comparable timings with --jobs N: one thread per child unless asked otherwise.
        self.env.setdefault("OMP_NUM_THREADS", "1")

    def command(self, v: Variant) -> list[str]:
        cmd = [self.python, "-m", "pfem2x", "run", self.scene]
        for o in v.overrides:
            cmd += ["--set", o]
        if self.variant:
            cmd += ["--variant", self.variant]
        return cmd + ["--out", str(self.out / "variants" / v.slug), "--quiet", "--overwrite"]

    def run(self, v: Variant) -> dict[str, Any]:
        """Run one variant; return the process record (exit code, times, peak memory)."""
        log = self.out / "logs" / f"{v.slug}.log"
        with open(log, "w", encoding="utf-8") as f:
            with self.lock:
                if self.stopping:
                    return {"exit_code": None, "message": "interrupted"}
                t0 = time.perf_counter()
                proc = subprocess.Popen(
                    self.command(v),
                    stdin=subprocess.DEVNULL,
                    stdout=f,
                    stderr=subprocess.STDOUT,
                    env=self.env,
                )
                self.procs[proc.pid] = proc
            # os.wait4 gives this child's own resource usage (also with --jobs > 1).
            _, status, ru = os.wait4(proc.pid, 0)
            wall = time.perf_counter() - t0
            proc.returncode = os.waitstatus_to_exitcode(status)
            with self.lock:
                self.procs.pop(proc.pid, None)
        # ru_maxrss is in KiB on Linux, bytes on macOS.
        rss = ru.ru_maxrss / (1024**2 if sys.platform == "darwin" else 1024)
        code = proc.returncode
        message = _last_line(log)
        if code < 0 and not message:
            message = f"killed by signal {-code}"
        return {
            "exit_code": code,
            "process_wall_seconds": wall,
            "process_cpu_seconds": ru.ru_utime + ru.ru_stime,
            "peak_rss_mb": rss,
            "message": message,
            "command": self.command(v),
        }

    def kill_all(self) -> None:
        with self.lock:
            self.stopping = True
            for proc in list(self.procs.values()):
                try:
                    proc.kill()
                except OSError:
                    pass


def _row(v: Variant, summary: dict[str, Any] | None, rec: dict[str, Any], resumed: bool) -> dict:
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
        if _is_number(x) and k not in row and k not in ("metrics", "message")
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


def _plot_value(row: dict[str, Any], metric: str | None) -> float | None:
    """``|metric|`` of an ok row with a finite value and wall time, else None."""
    if metric is None or row["status"] != "ok" or row.get("wall_seconds") is None:
        return None
    x = row["metrics"].get(metric)
    return abs(x) if x is not None and math.isfinite(x) else None


# --------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------
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


def _fmt(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "yes" if v else ""
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return json.dumps(v)
    return str(v)


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
    for k, vals in info["vary"].items():
        lines.append(f"- `--vary {k}={','.join(vals)}`")
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
        cells = [_fmt(r.get(k)) for k in keys] + [
            r["frame"],
            r["status"],
            _fmt(r["metrics"].get(metric)) if metric else "",
            _fmt(r["wall_seconds"]),
            _fmt(r["cpu_seconds"]),
            _fmt(r["steps"]),
            _fmt(r["dt"]),
            _fmt(r["courant_max"]),
            _fmt(r["peak_rss_mb"]),
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


def _log_axes(ax: Any, xs: Sequence[float], ys: Sequence[float]) -> None:
    if xs and min(xs) > 0:
        ax.set_xscale("log")
    if ys and min(ys) > 0:
        ax.set_yscale("log")


def write_plots(out: Path, info: dict[str, Any], rows: list[dict[str, Any]]) -> list[str]:
    """Write ``error_vs_wall.png`` and ``error_vs_dt.png``; return the file names written."""
    metric = info["metric"]
    pts = [(r, _plot_value(r, metric)) for r in rows]
    pts = [(r, y) for r, y in pts if y is not None]
    if not pts:
        return []
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    keys = info["keys"]
    ylabel = f"|{metric}|"
    written = []

    # Error against wall time: one curve per frame, the Pareto front marked.
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
            text = "\n".join(f"{k.split('.')[-1]}={_fmt(r[k])}" for k in keys)
            ax.annotate(text, (r["wall_seconds"], y), fontsize=6, xytext=(4, 4),
                        textcoords="offset points")  # fmt: skip
    _log_axes(ax, [r["wall_seconds"] for r, _ in pts], [y for _, y in pts])
    ax.set_xlabel("wall seconds (time stepping)")
    ax.set_ylabel(ylabel)
    ax.set_title(f"{info['scene']}: error against wall time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "error_vs_wall.png", dpi=110)
    plt.close(fig)
    written.append("error_vs_wall.png")

    # Error against dt and Courant: one curve per frame and other varied keys.
    others = [k for k in keys if k not in ("time.dt", "time.courant", "method.frame")]
    groups: dict[str, list[tuple[dict, float]]] = {}
    for r, y in pts:
        label = " ".join([r["frame"]] + [f"{k.split('.')[-1]}={_fmt(r[k])}" for k in others])
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
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(f"{info['scene']}: error against Δt and Courant number")
    fig.tight_layout()
    fig.savefig(out / "error_vs_dt.png", dpi=110)
    plt.close(fig)
    written.append("error_vs_dt.png")
    return written


# --------------------------------------------------------------------------
# Driver
# --------------------------------------------------------------------------
#: marker file of a study folder (written when the study starts)
STUDY_MARKER = ".pfem2x-study"


def _check_out_dir(out: Path) -> None:
    """Refuse a study folder that is a file or a non-empty folder without the study marker."""
    if out.exists() and not out.is_dir():
        raise StudyError(f"--out {out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not (out / STUDY_MARKER).is_file():
        raise StudyError(
            f"--out {out}: a non-empty folder that is not a pfem2x study folder (no "
            f"{STUDY_MARKER} marker; studies written by older versions have none): "
            f"use another folder, or remove it by hand"
        )


def run_study(
    scene: str,
    vary: Sequence[str],
    sets: Sequence[str] = (),
    variant: str | None = None,
    jobs: int = 1,
    out: str | os.PathLike | None = None,
    metric: str | None = None,
    quiet: bool = False,
    python: str | None = None,
) -> StudyResult:
    """Run (or resume) a study and write its tables and plots.

    Parameters
    ----------
    scene:
        A scene file or built-in scene name.
    vary:
        ``KEY=V1,V2,...`` strings; their cartesian product is run.
    sets:
        ``KEY=VALUE`` overrides common to every variant.
    variant:
        The scene's ``[variants.NAME]``.
    jobs:
        Variants run at once.
    out:
        Study folder (default ``studies/<scene name>``).
    metric:
        The error metric plotted (default: see :data:`DEFAULT_METRICS`).
    quiet:
        No progress on stderr.
    python:
        Interpreter for the children (default: this one).

    Returns
    -------
    StudyResult
        Exit code 0 when the study ran, whatever the variants' statuses.

    Raises
    ------
    SceneError
        On bad input, before anything is run or written.
    """
    if jobs < 1:
        raise StudyError(f"--jobs: must be >= 1, got {jobs}")
    base, variants = plan_study(scene, vary, sets, variant)
    if out is None:
        out_dir = Path("studies") / base.name
        check_default_out(out_dir, "studies")
    else:
        out_dir = Path(out)
    _check_out_dir(out_dir)
    keys = list(variants[0].texts)
    info: dict[str, Any] = {
        "scene": base.name,
        "source": base.source,
        "variant": variant,
        "sets": list(sets),
        "vary": {k: [] for k in keys},
        "keys": keys,
        "metric": metric,
        "python": python or sys.executable,
    }
    for v in variants:
        for k, t in v.texts.items():
            if t not in info["vary"][k]:
                info["vary"][k].append(t)

    (out_dir / "variants").mkdir(parents=True, exist_ok=True)
    (out_dir / "logs").mkdir(exist_ok=True)
    (out_dir / STUDY_MARKER).write_text("a pfem2x study folder\n")
    rows: dict[str, dict[str, Any]] = {}
    todo: list[Variant] = []
    for v in variants:
        vdir = out_dir / "variants" / v.slug
        summary = _is_done(v, vdir)
        if summary is None:
            todo.append(v)
        else:
            rec = _read_json(vdir / RUN_RECORD) or {}
            rows[v.slug] = _row(v, summary, rec, resumed=True)

    say = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    n = len(variants)
    say(
        f"study: {n} variants of {base.name}, {n - len(todo)} done already, "
        f"{len(todo)} to run ({jobs} at once) -> {out_dir}"
    )
    bar = _progress(len(todo), quiet)
    if bar is not None:
        say = lambda msg: bar.write(msg, file=sys.stderr)  # noqa: E731
    runner = _Runner(python or sys.executable, scene, variant, out_dir)
    done = n - len(todo)
    interrupted = False
    pool = ThreadPoolExecutor(max_workers=jobs)
    try:
        futures = {pool.submit(runner.run, v): v for v in todo}
        for fut in as_completed(futures):
            v = futures[fut]
            rec = fut.result()
            vdir = out_dir / "variants" / v.slug
            summary = _read_json(vdir / "summary.json")
            if vdir.is_dir():
                atomic_write_text(vdir / RUN_RECORD, json.dumps(rec, indent=2) + "\n")
            row = _row(v, summary, rec, resumed=False)
            rows[v.slug] = row
            done += 1
            if bar is not None:
                bar.update(1)
            say(f"[{done}/{n}] {v.label()}: {_progress_text(row, metric)}")
    except KeyboardInterrupt:
        interrupted = True
        runner.kill_all()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if bar is not None:
            bar.close()

    ordered = [rows[v.slug] for v in variants if v.slug in rows]
    chosen = choose_metric(ordered, metric)
    info["metric"] = chosen
    pts = [(i, _plot_value(r, chosen)) for i, r in enumerate(ordered)]
    pts = [(i, y) for i, y in pts if y is not None]
    front = {pts[j][0] for j in pareto_front([(ordered[i]["wall_seconds"], y) for i, y in pts])}
    for i, r in enumerate(ordered):
        r["pareto"] = i in front
    info["pareto"] = [ordered[i]["run"] for i in sorted(front)]
    write_tables(out_dir, info, ordered)
    plots = [] if interrupted else write_plots(out_dir, info, ordered)
    write_markdown(out_dir, info, ordered, plots)
    result = StudyResult(EXIT_OK, out_dir, ordered, chosen, len(todo))
    if interrupted:
        print("error: interrupted (run the same command again to resume)", file=sys.stderr)
        result.exit_code = EXIT_INTERRUPTED
        return result
    if metric is not None and chosen is None:
        names = sorted({k for r in ordered for k in r["metrics"]})
        print(
            f"error: --metric {metric}: not a metric of this study (has: "
            f"{', '.join(names) or 'none'}); rerun with another --metric (nothing is rerun)",
            file=sys.stderr,
        )
        result.exit_code = EXIT_BAD_INPUT
        return result
    counts = {s: sum(r["status"] == s for r in ordered) for s in ("ok", "diverged", "failed")}
    say(
        f"study done: {', '.join(f'{c} {s}' for s, c in counts.items() if c)}; "
        f"{out_dir / 'study.md'}"
    )
    return result


def _progress_text(row: dict[str, Any], metric: str | None) -> str:
    if row["status"] != "ok":
        return f"{row['status']} (exit {row['exit_code']}): {row['message']}"
    name = choose_metric([row], metric) or choose_metric([row])
    err = f", {name} = {row['metrics'][name]:.4g}" if name else ""
    return f"ok{err}, {row['steps']} steps, {row['wall_seconds']:.3g} s"


def _progress(total: int, quiet: bool) -> Any:
    if quiet or total == 0 or os.environ.get("CI") or not sys.stderr.isatty():
        return None
    try:
        from tqdm import tqdm  # noqa: PLC0415
    except ImportError:
        return None
    return tqdm(total=total, desc="study", unit="variant", file=sys.stderr, leave=False)


# --------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------
def add_study_parser(sub: Any) -> argparse.ArgumentParser:
    """Add the ``study`` sub-command to ``sub`` (an argparse sub-parsers object)."""
    s = sub.add_parser(
        "study",
        help="run the product of --vary lists of a scene; tabulate and plot error against time",
    )
    s.add_argument("scene", help="a scene file (.toml) or a built-in scene name")
    s.add_argument(
        "--vary",
        action="append",
        required=True,
        metavar="KEY=V1,V2,...",
        help="a key and its values (TOML; commas inside [...] do not split)",
    )
    s.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override for every run"
    )
    s.add_argument("--variant", help="apply the scene's [variants.NAME] (e.g. small)")
    s.add_argument("--jobs", type=int, default=1, help="variants run at once (default 1)")
    s.add_argument("--out", help="study folder (default studies/SCENE); reruns resume")
    s.add_argument("--metric", help="error metric plotted (default: l2_error_time_avg, ...)")
    s.add_argument("--quiet", action="store_true", help="no progress on stderr")
    return s


def study_main(args: argparse.Namespace) -> int:
    """Run ``pfem2x study`` from parsed arguments; return the exit code.

    SIGTERM is handled like Ctrl-C: the running children are killed, the tables
    of the finished variants written, exit 130.
    """

    def _term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, _term)
    try:
        res = run_study(
            args.scene,
            args.vary,
            args.set,
            args.variant,
            jobs=args.jobs,
            out=args.out,
            metric=args.metric,
            quiet=args.quiet,
        )
    except SceneError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:  # before or after the children ran
        print("error: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, old)
    return res.exit_code
