"""Study children: each variant runs in its own ``python -m pfem2x run`` process.

:class:`ChildRunner` starts the children, measures their wall and CPU seconds and
peak memory (``os.wait4``) and kills the ones still running on interrupt;
:func:`is_done` tells whether a variant's folder holds a finished run (resume).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from pfem2x.study.plan import Variant
from pfem2x.study.rows import DONE_STATUSES

#: Process measurements saved next to each variant's summary (for resumed rows).
RUN_RECORD = "study-run.json"


def read_json(path: Path) -> dict[str, Any] | None:
    """The JSON object in ``path``, or None if it is missing, unreadable or not an object."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    return data if isinstance(data, dict) else None


def is_done(v: Variant, vdir: Path) -> dict[str, Any] | None:
    """The summary of a finished run of ``v`` in ``vdir`` (same resolved scene), else None."""
    summary = read_json(vdir / "summary.json")
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


class ChildRunner:
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
        """The child's command line for ``v``."""
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
        """Kill the running children; start no more."""
        with self.lock:
            self.stopping = True
            for proc in list(self.procs.values()):
                try:
                    proc.kill()
                except OSError:
                    pass
