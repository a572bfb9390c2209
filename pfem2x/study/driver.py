"""Study driver: :func:`run_study` plans, resumes, runs the children and writes the report.

Serial: the children do the work; this module imports neither DOLFINx nor MPI.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pfem2x.io import atomic_write_text
from pfem2x.output import check_default_out, make_folder
from pfem2x.scene import Scene
from pfem2x.study.children import RUN_RECORD, ChildRunner, is_done, read_json
from pfem2x.study.plan import StudyError, Variant, plan_study
from pfem2x.study.plots import write_plots
from pfem2x.study.report import write_markdown, write_tables
from pfem2x.study.rows import choose_metric, make_row, pareto_front, plot_value

EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130
#: marker file of a study folder (written when the study starts)
STUDY_MARKER = ".pfem2x-study"


@dataclass
class StudyResult:
    """What :func:`run_study` produced."""

    exit_code: int
    out_dir: Path
    rows: list[dict[str, Any]] = field(default_factory=list)
    metric: str | None = None
    ran: int = 0


def _check_out_dir(out: Path, name: str) -> None:
    """Refuse a study folder that is a file, a non-empty folder without the study marker,
    or the study folder of another scene than ``name``."""
    try:
        if out.exists() and not out.is_dir():
            raise StudyError(f"--out {out}: exists and is not a folder")
        if out.is_dir() and any(out.iterdir()) and not (out / STUDY_MARKER).is_file():
            raise StudyError(
                f"--out {out}: a non-empty folder that is not a pfem2x study folder (no "
                f"{STUDY_MARKER} marker; studies written by older versions have none): "
                f"use another folder, or remove it by hand"
            )
    except OSError as exc:
        raise StudyError(f"--out {out}: cannot read study folder ({exc.strerror or exc})") from None
    held = _study_scene(out)
    if held is not None and held != name:
        raise StudyError(
            f"--out {out}: holds a study of scene {held!r}, not {name!r}: use another "
            f"--out, or remove it by hand"
        )


def _study_scene(out: Path) -> str | None:
    """The scene of the study in ``out`` (its marker, else its ``study.json``), or None."""
    for path in (out / STUDY_MARKER, out / "study.json"):
        data = read_json(path)
        if data is not None and isinstance(data.get("scene"), str):
            return data["scene"]
    return None


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
    out_dir = _study_dir(out, base.name)
    info = _study_info(base, variants, vary, variant, sets, metric, python)
    rows, todo = _start(out_dir, variants, base.name)

    say = (lambda msg: None) if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    n = len(variants)
    say(
        f"study: {n} variants of {base.name}, {n - len(todo)} done already, "
        f"{len(todo)} to run ({jobs} at once) -> {out_dir}"
    )
    bar = _progress(len(todo), quiet)
    if bar is not None:
        say = lambda msg: bar.write(msg, file=sys.stderr)  # noqa: E731
    runner = ChildRunner(python or sys.executable, scene, variant, out_dir)
    interrupted = _run_children(runner, todo, rows, jobs, n, metric, say, bar)
    ordered = [rows[v.slug] for v in variants if v.slug in rows]
    return _finish(out_dir, info, ordered, metric, len(todo), interrupted, say)


def _study_dir(out: str | os.PathLike | None, name: str) -> Path:
    """The study folder: ``out``, else ``studies/<name>``; refused if not a study folder."""
    if out is None:
        out_dir = Path("studies") / name
        check_default_out(out_dir, "studies")
    else:
        out_dir = Path(out)
    _check_out_dir(out_dir, name)
    return out_dir


def _study_info(
    base: Scene,
    variants: Sequence[Variant],
    vary: Sequence[str],
    variant: str | None,
    sets: Sequence[str],
    metric: str | None,
    python: str | None,
) -> dict[str, Any]:
    """The study's description (the head of ``study.json``)."""
    keys = list(variants[0].texts)
    info: dict[str, Any] = {
        "scene": base.name,
        "source": base.source,
        "variant": variant,
        "sets": list(sets),
        "vary": {k: [] for k in keys},
        "axes": list(vary),  # the --vary texts: keys varied together stay one axis
        "keys": keys,
        "metric": metric,
        "python": python or sys.executable,
    }
    for v in variants:
        for k, t in v.texts.items():
            if t not in info["vary"][k]:
                info["vary"][k].append(t)
    return info


def _start(
    out_dir: Path, variants: Sequence[Variant], name: str
) -> tuple[dict[str, dict[str, Any]], list[Variant]]:
    """Make the study folder of scene ``name``; return the rows of the finished variants
    and the others."""
    marker = json.dumps({"about": "a pfem2x study folder", "scene": name}) + "\n"
    err = make_folder(out_dir, STUDY_MARKER, marker, "study folder")
    try:
        (out_dir / "variants").mkdir(exist_ok=True)
        (out_dir / "logs").mkdir(exist_ok=True)
    except OSError as exc:
        err = err or f"{out_dir}: cannot write study folder ({exc.strerror or exc})"
    if err:
        raise StudyError(f"--out {err}")
    rows: dict[str, dict[str, Any]] = {}
    todo: list[Variant] = []
    for v in variants:
        vdir = out_dir / "variants" / v.slug
        summary = is_done(v, vdir)
        if summary is None:
            todo.append(v)
        else:
            rec = read_json(vdir / RUN_RECORD) or {}
            rows[v.slug] = make_row(v, summary, rec, resumed=True)
    return rows, todo


def _run_children(
    runner: ChildRunner,
    todo: Sequence[Variant],
    rows: dict[str, dict[str, Any]],
    jobs: int,
    n: int,
    metric: str | None,
    say: Callable[[str], None],
    bar: Any,
) -> bool:
    """Run ``todo``, ``jobs`` at once, adding their rows to ``rows``; True if interrupted."""
    done = n - len(todo)
    interrupted = False
    pool = ThreadPoolExecutor(max_workers=jobs)
    try:
        futures = {pool.submit(runner.run, v): v for v in todo}
        for fut in as_completed(futures):
            v = futures[fut]
            rec = fut.result()
            vdir = runner.out / "variants" / v.slug
            summary = read_json(vdir / "summary.json")
            if vdir.is_dir():
                atomic_write_text(vdir / RUN_RECORD, json.dumps(rec, indent=2) + "\n")
            row = make_row(v, summary, rec, resumed=False)
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
    return interrupted


def _mark_pareto(ordered: list[dict[str, Any]], metric: str | None) -> list[str]:
    """Set each row's ``pareto`` flag; return the runs on the front."""
    pts = [(i, plot_value(r, metric)) for i, r in enumerate(ordered)]
    pts = [(i, y) for i, y in pts if y is not None]
    front = {pts[j][0] for j in pareto_front([(ordered[i]["wall_seconds"], y) for i, y in pts])}
    for i, r in enumerate(ordered):
        r["pareto"] = i in front
    return [ordered[i]["run"] for i in sorted(front)]


def _finish(
    out_dir: Path,
    info: dict[str, Any],
    ordered: list[dict[str, Any]],
    metric: str | None,
    ran: int,
    interrupted: bool,
    say: Callable[[str], None],
) -> StudyResult:
    """Write the tables, plots and ``study.md``; report; return the result."""
    chosen = choose_metric(ordered, metric)
    info["metric"] = chosen
    info["pareto"] = _mark_pareto(ordered, chosen)
    write_tables(out_dir, info, ordered)
    plots = [] if interrupted else write_plots(out_dir, info, ordered)
    write_markdown(out_dir, info, ordered, plots)
    result = StudyResult(EXIT_OK, out_dir, ordered, chosen, ran)
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
