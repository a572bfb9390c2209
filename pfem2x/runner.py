"""The runner: owns time, Courant control, diagnostics, output and progress.

Solvers never print; the runner prints on rank 0 only (and not with ``quiet``).
"""

from __future__ import annotations

import math
import os
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfem2x import compat, fem
from pfem2x import io as pio
from pfem2x.compat import MPI
from pfem2x.mesh import Domain, MeshError, build_mesh
from pfem2x.physics.base import Diverged, Solver  # noqa: F401 - Diverged raised here too
from pfem2x.scene import Scene, SceneError

__all__ = ["RunResult", "Simulation", "build_domain", "make_solver", "prepare_output"]

EXIT_OK, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 2, 3


@dataclass
class RunResult:
    """What a run produced."""

    status: str
    exit_code: int
    out_dir: Path
    summary: dict[str, Any] = field(default_factory=dict)
    history: list[dict[str, float]] = field(default_factory=list)


def build_domain(scene: Scene, comm: MPI.Comm) -> Domain:
    """The scene's mesh as a :class:`~pfem2x.mesh.Domain` (SceneError on bad mesh input)."""
    m = scene["mesh"]
    try:
        return build_mesh(
            comm,
            m["kind"],
            bounds=m["bounds"],
            cells=m["cells"],
            diagonal=m["diagonal"],
            file=m["file"],
            periodic=m["periodic"],
        )
    except MeshError as exc:
        raise SceneError(str(exc)) from None


def make_solver(scene: Scene, domain: Domain) -> Solver:
    """The solver for the scene's physics and frame; only the scene's effects are built."""
    physics = scene["scene"]["physics"]
    if physics == "transport":
        from pfem2x.physics.transport import make_transport_solver  # noqa: PLC0415

        return make_transport_solver(scene, domain)
    if physics == "flow":
        from pfem2x.physics.flow import make_flow_solver  # noqa: PLC0415

        return make_flow_solver(scene, domain)
    raise SceneError(f"scene.physics: {physics!r} is not available yet")


def prepare_output(comm: MPI.Comm, out_dir: Path, overwrite: bool) -> None:
    """Create the output folder; refuse an existing non-empty one unless ``overwrite``."""
    err = ""
    if comm.rank == 0:
        try:
            if out_dir.exists() and not out_dir.is_dir():
                err = f"{out_dir}: exists and is not a folder"
            elif out_dir.exists() and any(out_dir.iterdir()):
                if not overwrite:
                    err = f"{out_dir}: output folder exists (use --overwrite or another --out)"
                else:
                    shutil.rmtree(out_dir)
            if not err:
                out_dir.mkdir(parents=True, exist_ok=True)
                probe = out_dir / ".pfem2x-write-test"
                probe.write_text("")
                probe.unlink()
        except OSError as exc:
            err = f"{out_dir}: cannot write output folder ({exc.strerror or exc})"
    err = comm.bcast(err, root=0)
    if err:
        raise SceneError(err)


def time_grid(scene: Scene, domain: Domain, solver: Solver) -> tuple[float, int]:
    """``(dt, steps)``: a uniform step landing exactly on ``t_end``."""
    t_end = scene["time"]["t_end"]
    dt = scene["time"]["dt"]
    if dt is None:
        vmax = solver.max_velocity(0.0)
        if vmax <= 0.0:
            raise SceneError("time.courant: the velocity is zero at t = 0; give time.dt instead")
        dt = scene["time"]["courant"] * domain.min_h() / vmax
    steps = max(1, math.ceil(t_end / dt - 1e-9))
    if steps > scene["time"]["max_steps"]:
        raise SceneError(
            f"time: {steps} steps exceed time.max_steps = {scene['time']['max_steps']}"
        )
    return t_end / steps, steps


class Simulation:
    """One run of a scene into an output folder.

    Parameters
    ----------
    scene:
        The validated scene.
    out_dir:
        Output folder (created; see :func:`prepare_output`).
    comm:
        MPI communicator.
    quiet:
        No progress bar or messages.
    overwrite:
        Replace an existing output folder.
    """

    def __init__(
        self,
        scene: Scene,
        out_dir: str | os.PathLike,
        comm: MPI.Comm | None = None,
        quiet: bool = False,
        overwrite: bool = False,
    ):
        self.scene = scene
        self.comm = comm or MPI.COMM_WORLD
        self.out = Path(out_dir)
        self.quiet = quiet
        self.overwrite = overwrite
        self.rank0 = self.comm.rank == 0

    def say(self, msg: str) -> None:
        """Print on rank 0 unless quiet."""
        if self.rank0 and not self.quiet:
            print(msg, file=sys.stderr, flush=True)

    def setup(self) -> None:
        """Build mesh and solver (SceneError on bad input), then create the output folder."""
        wall0 = time.perf_counter()
        self.domain = build_domain(self.scene, self.comm)
        fem.reset_counters()
        self.solver = make_solver(self.scene, self.domain)
        self.dt, self.steps = time_grid(self.scene, self.domain, self.solver)
        prepare_output(self.comm, self.out, self.overwrite)
        self.setup_seconds = time.perf_counter() - wall0

    def run(self) -> RunResult:
        """Set up, step to ``t_end`` with output and diagnostics, write the summary."""
        self.setup()
        sc, out, comm = self.scene, self.out, self.comm
        outp = sc["output"]
        if self.rank0:
            pio.atomic_write_text(out / "scene.toml", sc.resolved_toml())
        fields = self.solver.fields()
        fw = (
            pio.FieldWriter(comm, out / "fields.xdmf", self.domain.mesh)
            if outp["fields"] and fields
            else None
        )
        csvw = pio.CSVWriter(comm, out / "diagnostics.csv") if outp["csv"] else None
        cloud = self.solver.cloud()
        pw = pio.ParticleWriter(comm, out) if (outp["particles"] and cloud is not None) else None
        png_times = sorted(
            outp["png_times"] or ([] if not outp["png"] else [0.0, sc["time"]["t_end"]])
        )
        every = outp["every"]
        h_min = self.domain.min_h()

        history: list[dict[str, float]] = []
        t_end = sc["time"]["t_end"]
        adaptive = bool(sc["time"]["adaptive"]) and sc["time"]["courant"] is not None
        t, dt = 0.0, self.dt
        t_good = 0.0
        courant_max = 0.0
        status, code, message = "ok", EXIT_OK, ""
        next_out = every if every > 0 else math.inf
        png_i = 0
        last_good = self.solver.state()
        cpu0, wall0 = time.process_time(), time.perf_counter()
        step_wall: list[float] = []
        dts: list[float] = []
        last_out = [-1]

        def write_outputs(step: int, t: float) -> None:
            last_out[0] = step
            if fw is not None:
                fw.write(self.solver.fields(), t)
            if pw is not None:
                pw.write(*particle_arrays(self.solver.cloud()), t, step)
            segs = self.solver.interfaces()
            if segs is not None:
                if self.rank0:
                    (out / "interface").mkdir(exist_ok=True)
                pio.write_interface(comm, out / "interface" / f"interface_t{t:010.5f}.csv", segs)

        def snapshots(t: float, final: bool = False) -> None:
            nonlocal png_i
            while png_i < len(png_times) and (t >= png_times[png_i] - 0.5 * dt or final):
                if outp["png"]:
                    name, u = self.solver.snapshot_field()
                    pio.png_snapshot(
                        out / f"{name}_t{png_times[png_i]:08.3f}.png",
                        u,
                        f"{sc.name}  {name}  {self.solver.time_label(t)}",
                    )
                png_i += 1
                if final:
                    break

        d0 = self.solver.diagnostics(t)
        d0.update({"step": 0, "t": t})
        history.append(d0)
        if csvw:
            csvw.write(_row(d0, 0.0, self.solver))
        write_outputs(0, t)
        snapshots(t)

        bar = self._progress(self.steps)
        step = 0
        max_steps = sc["time"]["max_steps"]
        try:
            while t < t_end - 1e-12 * max(1.0, t_end):
                step += 1
                if step > max_steps:
                    raise Diverged(f"time.max_steps = {max_steps} reached at t = {t:.6g}")
                ts = time.perf_counter()
                vmax = self.solver.max_velocity(t)
                if adaptive:
                    # Keep the requested Courant number; grow at most 20 % per step, and
                    # split the remainder rather than end on a sliver of a step.
                    if vmax > 0:
                        dt = min(sc["time"]["courant"] * h_min / vmax, 1.2 * dt)
                    left = t_end - t
                    dt = left if dt >= left * (1 - 1e-9) else min(dt, 0.5 * left)
                courant_max = max(courant_max, vmax * dt / h_min)
                self.solver.step(t, dt)
                if adaptive:
                    t = t_end if dt == t_end - t else t + dt
                else:
                    t = step * self.dt if step < self.steps else t_end
                self.solver.check_finite(t)
                step_wall.append(time.perf_counter() - ts)
                dts.append(dt)
                d = self.solver.diagnostics(t)
                d.update({"step": step, "t": t})
                history.append(d)
                if csvw:
                    csvw.write(_row(d, step_wall[-1], self.solver))
                last_good = self.solver.state()
                t_good = t
                if t >= next_out - 0.5 * dt:
                    write_outputs(step, t)
                    while next_out <= t + 0.5 * dt:
                        next_out += every
                snapshots(t)
                if bar is not None:
                    bar.update(1)
        except FloatingPointError as exc:  # Diverged, or a linear solver that diverged
            status, code = "diverged", EXIT_DIVERGED
            message = (
                f"diverged in step {step} (t = {t_good:.6g} -> {t_good + dt:.6g}, "
                f"{self.solver.time_label(t_good + dt)}): {exc}"
            )
            self.solver.restore(last_good)
            lg = pio.FieldWriter(comm, out / "last_good.xdmf", self.domain.mesh)
            lg.write(self.solver.fields(), t_good)
            lg.close()
            t = t_good
        finally:
            if bar is not None:
                bar.close()
        if status == "ok":
            if last_out[0] != step:
                write_outputs(step, t)
            snapshots(t, final=True)
        if fw:
            fw.close()
        if csvw:
            csvw.close()
        wall = time.perf_counter() - wall0
        cpu = comm.allreduce(time.process_time() - cpu0, op=MPI.SUM)
        timings = {k: comm.allreduce(v, op=MPI.MAX) for k, v in self.solver.timings.items()}
        summary = {
            "scene": sc.name,
            "source": sc.source,
            "physics": sc["scene"]["physics"],
            "frame": sc.frame,
            "solver": self.solver.name,
            "effects": [k for k, v in sc.effects.items() if v],
            "status": status,
            "message": message,
            "steps": len(history) - 1,
            "t_end": float(t),
            "dt": float(np.max(dts)) if dts else float(dt),
            "dt_min": float(np.min(dts)) if dts else float(dt),
            "adaptive_dt": adaptive,
            "courant_max": float(courant_max),
            "h_min": float(h_min),
            "cells": self.domain.num_cells_global(),
            "wall_seconds": float(wall),
            "setup_seconds": float(self.setup_seconds),
            "cpu_seconds": float(cpu),
            "step_wall_median": float(np.median(step_wall)) if step_wall else 0.0,
            "timings": timings,
            "operators": dict(fem.COUNTERS),
            "dolfinx_version": compat.dolfinx.__version__,
            "mpi_size": comm.size,
            "metrics": self.solver.metrics(history),
        }
        if self.rank0:
            pio.write_json(out / "summary.json", summary)
        if status == "ok":
            self.say(
                f"done: {len(history) - 1} steps, dt = {dt:.4g}, "
                f"Courant max {courant_max:.3g}, {wall:.1f} s -> {out}"
            )
        else:
            self.say(f"error: {message}; last good state in {out / 'last_good.xdmf'}")
        return RunResult(status, code, out, summary, history)

    def _progress(self, total: int) -> Any:
        if not self.rank0 or self.quiet or os.environ.get("CI") or not sys.stderr.isatty():
            return None
        try:
            from tqdm import tqdm  # noqa: PLC0415
        except ImportError:
            return None
        return tqdm(total=total, desc=self.scene.name, unit="step", file=sys.stderr, leave=False)


def particle_arrays(cloud: Any) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Positions and fields of a particle cloud for output."""
    pos = np.asarray(cloud.x)
    fields = {k: np.asarray(cloud.field(k)) for k in cloud.field_names}
    return pos, fields


def _row(d: dict[str, float], wall: float, solver: Solver) -> dict[str, Any]:
    row = {"step": d["step"], "t": d["t"]}
    row.update({k: v for k, v in d.items() if k not in ("step", "t")})
    row["wall_step"] = wall
    return row
