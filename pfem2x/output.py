"""Scheduled output of a run: the output folder, writers with their schedules, the summary.

Each writer has its own schedule: fields (XDMF), particles (PVD/VTP) and
interface polylines every ``output.every`` (and at the first and last step),
PNG snapshots at ``output.png_times``, the diagnostics CSV every step. The
summary and the last good state (after a divergence) are written here too.

The output folder carries a marker file (:data:`MARKER`) written at the
start of every run: ``--overwrite`` replaces only a folder with that marker
(or an empty one), never a user's folder.
"""

from __future__ import annotations

import math
import os
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pfem2x import io as pio
from pfem2x.jit import numba_version
from pfem2x.scene import SceneError

if TYPE_CHECKING:
    from mpi4py import MPI

    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = [
    "MARKER",
    "AtTimes",
    "EveryInterval",
    "LastGood",
    "Outputs",
    "check_default_out",
    "make_folder",
    "prepare_output",
    "process_start_seconds",
    "removable",
]

#: marker file written into every run folder at the start of the run
MARKER = ".pfem2x-run"


# -- the output folder -----------------------------------------------------------------
def _protected(path: Path) -> bool:
    """Whether ``path`` is ``/``, the home folder or the current folder or one of its parents."""
    p = path.resolve()
    cwd = Path.cwd().resolve()
    try:
        home = Path.home().resolve()
    except (RuntimeError, KeyError):  # no home folder known
        home = Path(p.anchor)
    return p == Path(p.anchor) or p == home or p == cwd or p in cwd.parents


def removable(path: Path, marker: str = MARKER) -> str:
    """``""`` when the non-empty folder ``path`` may be replaced, else the reason it may not.

    Only a folder written by pfem2x (holding ``marker``) may be replaced, and
    never ``/``, the home folder, or the current folder or one of its parents.
    """
    if _protected(path):
        return f"{path}: refusing to replace the root, home or current folder (or a parent of it)"
    if not (path / marker).is_file():
        return (
            f"{path}: not a pfem2x output folder (no {marker} marker; folders written by "
            f"older versions have none): not replaced; remove it by hand or use another folder"
        )
    return ""


def check_default_out(path: Path, root: str) -> None:
    """Refuse (:class:`SceneError`) a default output path that leaves the folder ``root``.

    The default folder is ``root/<scene name>``: it must be a sub-folder of ``root``.
    """
    base = Path(root).resolve()
    target = path.resolve()
    if target == base or base not in target.parents:
        raise SceneError(
            f"scene.name: the default output folder {path} is not inside {root}/ "
            f"(give --out or a plain scene name)"
        )


def make_folder(path: Path, marker: str, text: str, what: str = "output folder") -> str:
    """Create the folder ``path`` (and its parents) and write ``text`` to its ``marker`` file.

    Parameters
    ----------
    path:
        The folder; it may exist.
    marker:
        The name of the marker file written into it.
    text:
        The marker's content.
    what:
        The folder's kind, for the error text.

    Returns
    -------
    str
        ``""`` when done, else the error text naming ``path`` (a parent that is a file,
        a folder that cannot be created or written, ...).
    """
    try:
        path.mkdir(parents=True, exist_ok=True)
        (path / marker).write_text(text)
    except OSError as exc:
        return f"{path}: cannot write {what} ({exc.strerror or exc})"
    return ""


def prepare_output(comm: MPI.Comm, out_dir: Path, overwrite: bool) -> None:
    """Create the output folder and write its marker (collective).

    An existing non-empty folder is refused unless ``overwrite`` and it is a
    pfem2x run folder (:func:`removable`); then it is replaced. Raises
    :class:`SceneError` on every rank on refusal.
    """
    err = ""
    if comm.rank == 0:
        try:
            if out_dir.exists() and not out_dir.is_dir():
                err = f"{out_dir}: exists and is not a folder"
            elif out_dir.exists() and any(out_dir.iterdir()):
                if not overwrite:
                    err = f"{out_dir}: output folder exists (use --overwrite or another --out)"
                else:
                    err = removable(out_dir)
                    if not err:
                        shutil.rmtree(out_dir)
            if not err:
                err = make_folder(
                    out_dir, MARKER, "a pfem2x run folder: --overwrite may replace it\n"
                )
        except OSError as exc:
            err = f"{out_dir}: cannot write output folder ({exc.strerror or exc})"
    err = comm.bcast(err, root=0)
    if err:
        raise SceneError(err)


_FIRST_RUN = True


def process_start_seconds() -> float | None:
    """Seconds since this process started (Linux ``/proc``), or ``None`` where unknown."""
    try:
        with open("/proc/self/stat", encoding="ascii") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22: starttime, clock ticks after boot
        with open("/proc/uptime", encoding="ascii") as f:
            uptime = float(f.read().split()[0])
        return max(0.0, uptime - start_ticks / os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError, IndexError):
        return None


def startup_seconds(run_started: float) -> float:
    """Start-up time up to now: from the process start for the first run of a process,
    else (and where the process start is unknown) from ``run_started`` (``perf_counter``).
    """
    global _FIRST_RUN
    since_run = time.perf_counter() - run_started
    proc = process_start_seconds() if _FIRST_RUN else None
    _FIRST_RUN = False
    return float(max(proc, since_run) if proc is not None else since_run)


# -- schedules -------------------------------------------------------------------------
class EveryInterval:
    """Due every ``every`` time units (to half a step); never for ``every = 0``."""

    def __init__(self, every: float):
        self.every = every
        self.next = every if every > 0 else math.inf

    def due(self, t: float, dt: float) -> bool:
        """Whether output is due at ``t`` (step ``dt``)."""
        return t >= self.next - 0.5 * dt

    def advance(self, t: float, dt: float) -> None:
        """Move past ``t`` after writing."""
        while self.next <= t + 0.5 * dt:
            self.next += self.every


class AtTimes:
    """Due at each of the sorted ``times`` once (to half a step)."""

    def __init__(self, times: list[float]):
        self.times = sorted(times)
        self.i = 0

    def pending(self, t: float, dt: float, final: bool = False) -> list[float]:
        """The times now due (and consumed); ``final``: the next pending one, whenever it is."""
        out = []
        while self.i < len(self.times) and (t >= self.times[self.i] - 0.5 * dt or final):
            out.append(self.times[self.i])
            self.i += 1
            if final:
                break
        return out


def png_times(scene: Scene) -> list[float]:
    """The PNG snapshot times: none with ``output.png = false`` or ``png_times = []``,
    the first and last time when ``png_times`` is not given."""
    outp = scene.output
    if not outp.png:
        return []
    if outp.png_times is None:
        return [0.0, scene.time.t_end]
    return list(outp.png_times)


# -- writers ---------------------------------------------------------------------------
def particle_arrays(cloud: Any) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Positions and fields of a particle cloud for output."""
    pos = np.asarray(cloud.x)
    fields = {k: np.asarray(cloud.field(k)) for k in cloud.field_names}
    return pos, fields


class Outputs:
    """Every writer of a run, each on its schedule (collective calls).

    Parameters
    ----------
    scene, comm, out, domain, solver:
        The run.
    resume_step:
        The checkpoint step of a resumed run (``None`` for a new run): fields
        go to ``fields_resumed_N.xdmf`` and ``diagnostics.csv`` is continued.
    keep_rows:
        Rows of ``diagnostics.csv`` to keep when resuming.
    """

    def __init__(
        self,
        scene: Scene,
        comm: MPI.Comm,
        out: Path,
        domain: Domain,
        solver: Solver,
        resume_step: int | None = None,
        keep_rows: int | None = None,
    ):
        outp = scene.output
        self.scene, self.comm, self.out, self.solver = scene, comm, out, solver
        self.last_out = -1
        self.field_schedule = EveryInterval(outp.every)
        self.png_schedule = AtTimes(png_times(scene))
        cloud = solver.cloud()
        self.particles = (
            pio.ParticleWriter(comm, out, outp.particle_precision)
            if outp.particles and cloud is not None
            else None
        )
        xdmf = "fields.xdmf" if resume_step is None else f"fields_resumed_{resume_step}.xdmf"
        self.fields = (
            pio.FieldWriter(comm, out / xdmf, domain.mesh)
            if outp.fields and solver.fields()
            else None
        )
        self.csv = pio.CSVWriter(comm, out / "diagnostics.csv", keep_rows) if outp.csv else None

    # -- checkpoint state ---------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        """The schedules' state for a checkpoint (``loop`` keys of ``meta.json``)."""
        return {
            "next_out": self.field_schedule.next,
            "png_i": self.png_schedule.i,
            "last_out": self.last_out,
        }

    def load_state(self, loop: dict[str, Any], particle_outputs: list[Any]) -> None:
        """Restore :meth:`state` and the particle collection from a checkpoint."""
        self.field_schedule.next = loop["next_out"]
        self.png_schedule.i = loop["png_i"]
        self.last_out = loop["last_out"]
        if self.particles is not None:
            self.particles.entries = [tuple(e) for e in particle_outputs]

    def particle_entries(self) -> list[Any]:
        """The particle collection's entries (stored in checkpoints)."""
        return self.particles.entries if self.particles is not None else []

    # -- writing ------------------------------------------------------------------------
    def write_fields(self, step: int, t: float) -> None:
        """Fields, particles and interface at ``t`` (step ``step``)."""
        self.last_out = step
        if self.fields is not None:
            self.fields.write(self.solver.fields(), t)
        if self.particles is not None:
            self.particles.write(*particle_arrays(self.solver.cloud()), t, step)
        segs = self.solver.interfaces()
        if segs is not None:
            if self.comm.rank == 0:
                (self.out / "interface").mkdir(exist_ok=True)
            path = self.out / "interface" / f"interface_t{t:010.5f}.csv"
            pio.write_interface(self.comm, path, segs)

    def snapshots(self, t: float, dt: float, final: bool = False) -> None:
        """PNG snapshots due at ``t``; with ``final`` the next pending one (drawn now)."""
        for tp in self.png_schedule.pending(t, dt, final):
            name, u = self.solver.snapshot_field()
            # a time the run did not reach (beyond t_end, or a run that stopped early) is
            # drawn at the end under the time of the state it shows
            shown = tp if abs(t - tp) <= 0.5 * dt else t
            pio.png_snapshot(
                self.out / f"{name}_t{shown:08.3f}.png",
                u,
                f"{self.scene.name}  {name}  {self.solver.time_label(t)}",
                label=name,
                segments=self.solver.interfaces(),
            )

    def row(self, d: dict[str, float], wall: float) -> None:
        """One diagnostics row (every step)."""
        if self.csv is not None:
            row = {"step": d["step"], "t": d["t"]}
            row.update({k: v for k, v in d.items() if k not in ("step", "t")})
            row["wall_step"] = wall
            self.csv.write(row)

    def initial(self, d0: dict[str, float], dt: float) -> None:
        """Outputs of a new run at ``t = 0`` (``dt``: the first step)."""
        self.row(d0, 0.0)
        self.write_fields(0, 0.0)
        self.snapshots(0.0, dt)

    def after_step(self, step: int, t: float, dt: float, d: dict[str, float], wall: float) -> None:
        """Outputs after step ``step`` (time ``t``, step ``dt``)."""
        self.row(d, wall)
        if self.field_schedule.due(t, dt):
            self.write_fields(step, t)
            self.field_schedule.advance(t, dt)

    def finish(self, step: int, t: float, dt: float) -> None:
        """The last fields (if not written at this step) and the pending snapshot."""
        if self.last_out != step:
            self.write_fields(step, t)
        self.snapshots(t, dt, final=True)

    def close(self) -> None:
        """Close the files."""
        if self.fields is not None:
            self.fields.close()
        if self.csv is not None:
            self.csv.close()


class LastGood:
    """The last good state of a run, written for inspection after a divergence."""

    def __init__(self, comm: MPI.Comm, out: Path, domain: Domain, solver: Solver):
        self.comm, self.out, self.domain, self.solver = comm, out, domain, solver
        self.state: dict[str, Any] = {}
        self.keep()

    def keep(self) -> None:
        """Remember the solver's current state (in the arrays of the state before)."""
        self.state = self.solver.state(into=self.state)

    def write(self, t_good: float) -> None:
        """Restore the remembered state and write ``last_good.xdmf`` (+ particles) (collective)."""
        self.solver.restore(self.state)
        lg = pio.FieldWriter(self.comm, self.out / "last_good.xdmf", self.domain.mesh)
        lg.write(self.solver.fields(), t_good)
        lg.close()
        cloud = self.solver.cloud()
        if cloud is not None:
            pos, flds = particle_arrays(cloud)
            allp = self.comm.gather(pos, root=0)
            allf = self.comm.gather(flds, root=0)
            if self.comm.rank == 0:
                pio.write_vtp(
                    self.out / "last_good_particles.vtp",
                    np.concatenate(allp),
                    {k: np.concatenate([f[k] for f in allf]) for k in flds},
                )

    def where(self) -> str:
        """Where the last good state is, for the error message."""
        extra = " and last_good_particles.vtp" if self.solver.cloud() is not None else ""
        return f"{self.out / 'last_good.xdmf'}{extra}"


def summary(
    scene: Scene, comm: MPI.Comm, domain: Domain, solver: Solver, run: dict[str, Any]
) -> dict[str, Any]:
    """The run's ``summary.json`` content (collective: reduces timings over ranks).

    ``run`` holds the loop's figures: ``status``, ``message``, ``history``,
    ``dts``, ``step_wall``, ``t``, ``dt``, ``courant_max``, ``adaptive``,
    ``wall``, ``cpu`` (this rank), ``setup_seconds``, ``startup_seconds``,
    ``compile_seconds``, ``startup_timings`` (the solver's ``timings`` at the
    first step: the start-up's share of them, e.g. the initial pressure solve).
    """
    from pfem2x import aot, compat, fem  # noqa: PLC0415
    from pfem2x.compat import MPI  # noqa: PLC0415

    history, dts, step_wall = run["history"], run["dts"], run["step_wall"]
    timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in solver.timings.items()}
    return {
        "scene": scene.name,
        "source": scene.source,
        "physics": scene.physics,
        "frame": scene.frame,
        "solver": solver.name,
        "effects": [k for k, v in scene.effects.items() if v],
        "status": run["status"],
        "message": run["message"],
        "steps": len(history) - 1,
        "t_end": float(run["t"]),
        "dt": float(np.max(dts)) if dts else float(run["dt"]),
        "dt_min": float(np.min(dts)) if dts else float(run["dt"]),
        "adaptive_dt": run["adaptive"],
        "courant_max": float(run["courant_max"]),
        "h_min": float(domain.min_h()),
        "cells": domain.num_cells_global(),
        "wall_seconds": float(run["wall"]),
        "setup_seconds": float(run["setup_seconds"]),
        "startup_seconds": float(run["startup_seconds"]),
        "compile_seconds": float(run["compile_seconds"]),
        "cpu_seconds": float(comm.allreduce(run["cpu"], op=MPI.SUM)),
        "step_wall_median": float(np.median(step_wall)) if step_wall else 0.0,
        "timings": timings,
        "timings_startup": {
            k: comm.allreduce(v, op=MPI.MAX) for k, v in run.get("startup_timings", {}).items()
        },
        "operators": dict(fem.COUNTERS),
        "auto_keys": dict(solver.auto_keys),
        "dolfinx_version": compat.dolfinx.__version__,
        "numba_version": numba_version(),
        "kernels": "ahead of time" if aot.active() else "numba",
        "kernels_jit": sorted(set().union(*comm.allgather(aot.jit_kernels()))),
        "mpi_size": comm.size,
        "metrics": solver.metrics(history),
    }
