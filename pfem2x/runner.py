"""The runner: owns time, Courant control, diagnostics, output and progress.

Solvers never print; the runner prints on rank 0 only (and not with ``quiet``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pfem2x import compat, fem
from pfem2x import io as pio
from pfem2x.compat import MPI
from pfem2x.mesh import Domain, MeshError, build_mesh
from pfem2x.physics.base import Diverged, Solver  # noqa: F401 - Diverged raised here too
from pfem2x.scene import Scene, SceneError, validate

__all__ = [
    "RunResult",
    "Simulation",
    "build_domain",
    "find_checkpoint",
    "make_solver",
    "prepare_output",
]

EXIT_OK, EXIT_BAD_INPUT, EXIT_DIVERGED = 0, 2, 3
#: interrupted by SIGINT / SIGTERM (128 + signal number), after writing a checkpoint
EXIT_SIGINT, EXIT_SIGTERM = 130, 143


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
            partition=m["partition"],
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


@dataclass
class _Loop:
    """The runner's part of the run state: what a checkpoint stores besides the solver's."""

    step: int = 0
    t: float = 0.0
    dt: float = 0.0
    t_good: float = 0.0
    courant_max: float = 0.0
    next_out: float = math.inf
    png_i: int = 0
    last_out: int = -1
    energy0: float = 0.0
    energy_peak: float = 0.0
    wall_before: float = 0.0
    cpu_before: float = 0.0
    dts: list[float] = field(default_factory=list)
    step_wall: list[float] = field(default_factory=list)
    history: list[dict[str, float]] = field(default_factory=list)


#: names of the checkpoint folders in the output folder
CHECKPOINT, CHECKPOINT_TMP, CHECKPOINT_OLD = "checkpoint", ".checkpoint.tmp", ".checkpoint.old"


def find_checkpoint(out_dir: Path) -> tuple[Path, dict[str, Any]] | None:
    """The newest complete checkpoint of a run folder as ``(folder, meta)``, or ``None``.

    A checkpoint is complete when its ``meta.json`` (written last), its
    ``history.json`` and one ``rank{r}.npz`` per rank exist. ``checkpoint/``
    is tried first, then ``.checkpoint.old/`` (the previous one, kept while a
    new one is renamed into place); a ``.checkpoint.tmp/`` being written is
    never used.
    """
    for name in (CHECKPOINT, CHECKPOINT_OLD):
        d = out_dir / name
        try:
            meta = json.loads((d / "meta.json").read_text(encoding="utf-8"))
            size = int(meta["mpi_size"])
            if not (d / "history.json").is_file():
                continue
            if all((d / f"rank{r}.npz").is_file() for r in range(size)):
                return d, meta
        except (OSError, ValueError, KeyError, TypeError):
            continue
    return None


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

    Notes
    -----
    :meth:`resume` continues an interrupted run from its checkpoint.
    ``on_step(sim, step, t)``, if set, is called after every completed step.
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
        self.on_step: Callable[[Simulation, int, float], None] | None = None
        self._resume: tuple[Path, dict[str, Any]] | None = None
        self._signal = 0

    @classmethod
    def resume(
        cls, out_dir: str | os.PathLike, comm: MPI.Comm | None = None, quiet: bool = False
    ) -> Simulation:
        """A simulation that continues the run in ``out_dir`` from its checkpoint.

        The scene is the run's ``scene.toml`` (the resolved scene written at
        its start). Raises :class:`SceneError` without a complete checkpoint,
        when the scene file changed, or with another number of MPI ranks.
        """
        comm = comm or MPI.COMM_WORLD
        out = Path(out_dir)
        found, err = None, ""
        if comm.rank == 0:
            if not (out / "scene.toml").is_file():
                err = f"{out}: not a run folder (no scene.toml)"
            else:
                found = find_checkpoint(out)
                if found is None:
                    err = f"{out}: no complete checkpoint to resume from ({CHECKPOINT}/meta.json)"
        found, err = comm.bcast((found, err), root=0)
        if err:
            raise SceneError(err)
        ck, meta = found
        if int(meta["mpi_size"]) != comm.size:
            raise SceneError(
                f"{ck}: written by {meta['mpi_size']} MPI rank(s), this run has {comm.size}; "
                f"resume with the same number of ranks"
            )
        text = (out / "scene.toml").read_text(encoding="utf-8")
        if _digest(text) != meta["scene_hash"]:
            raise SceneError(f"{out / 'scene.toml'}: changed since the checkpoint was written")
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SceneError(f"{out / 'scene.toml'}: not valid TOML ({exc})") from None
        scene = validate(raw, source=meta["source"], base_dir=Path(meta["base_dir"]))
        sim = cls(scene, out, comm, quiet=quiet)
        sim._resume = (ck, meta)
        return sim

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
        if self._resume is None:
            prepare_output(self.comm, self.out, self.overwrite)
        self.setup_seconds = time.perf_counter() - wall0

    # -- signals ----------------------------------------------------------------
    def _on_signal(self, signum: int, frame: Any) -> None:
        if self._signal:  # a second signal: stop now, without a checkpoint
            raise KeyboardInterrupt
        self._signal = signum

    def _install_signals(self) -> dict[int, Any]:
        if threading.current_thread() is not threading.main_thread():
            return {}
        old = {}
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, self._on_signal)
        return old

    # -- checkpoints ------------------------------------------------------------
    def _write_checkpoint(self, lp: _Loop, pw: Any) -> str:
        """Write ``checkpoint/`` atomically (collective); returns an error text or ``""``."""
        comm, out = self.comm, self.out
        tmp, final, old = out / CHECKPOINT_TMP, out / CHECKPOINT, out / CHECKPOINT_OLD
        data = self.solver.checkpoint()
        err = ""
        if self.rank0:
            try:
                shutil.rmtree(tmp, ignore_errors=True)
                tmp.mkdir()
            except OSError as exc:
                err = f"{tmp}: {exc.strerror or exc}"
        err = comm.bcast(err, root=0)
        if err:
            return err
        try:
            with open(tmp / f"rank{comm.rank}.npz", "wb") as f:
                np.savez(f, **data)
        except OSError as exc:
            err = f"{tmp}: {exc.strerror or exc}"
        errs = comm.allgather(err)
        err = next((e for e in errs if e), "")
        if err:
            return err
        if self.rank0:
            try:
                meta = {
                    "format": 1,
                    "step": lp.step,
                    "t": lp.t,
                    "dt": lp.dt,
                    "mpi_size": comm.size,
                    "scene_hash": _digest(self.scene.resolved_toml()),
                    "source": self.scene.source,
                    "base_dir": str(self.scene.base_dir),
                    "dolfinx_version": compat.dolfinx.__version__,
                    "loop": {k: v for k, v in vars(lp).items() if k != "history"},
                    "operators": dict(fem.COUNTERS),
                    "particle_outputs": pw.entries if pw is not None else [],
                }
                pio.atomic_write_text(tmp / "history.json", json.dumps(lp.history))
                pio.write_json(tmp / "meta.json", meta)  # last: marks the folder complete
                if final.exists():
                    shutil.rmtree(old, ignore_errors=True)
                    os.replace(final, old)
                os.replace(tmp, final)
                shutil.rmtree(old, ignore_errors=True)
            except OSError as exc:
                err = f"{final}: {exc.strerror or exc}"
        return comm.bcast(err, root=0)

    def _load_checkpoint(self, pw: Any) -> _Loop:
        """Restore the solver and the loop state from the checkpoint (collective)."""
        ck, meta = self._resume
        history = None
        if self.rank0:
            history = json.loads((ck / "history.json").read_text(encoding="utf-8"))
        history = self.comm.bcast(history, root=0)

        def load(r: int) -> dict[str, np.ndarray]:
            with np.load(ck / f"rank{r}.npz") as f:
                return {k: f[k] for k in f.files}

        data = load(self.comm.rank)
        err = ""
        try:
            self.solver.restore_checkpoint(data, load)
        except ValueError as exc:
            err = f"{ck}: {exc}"
        errs = self.comm.allgather(err)
        err = next((e for e in errs if e), "")
        if err:
            raise SceneError(err)
        fem.COUNTERS.update(meta["operators"])
        if pw is not None:
            pw.entries = [tuple(e) for e in meta["particle_outputs"]]
        return _Loop(**meta["loop"], history=history)

    # -- guards -----------------------------------------------------------------
    def _guard(self, lp: _Loop, courant: float, d: dict[str, float]) -> None:
        """Raise :class:`Diverged` on a runaway Courant number or kinetic energy."""
        tm = self.scene["time"]
        if 0.0 < self.max_courant < courant:
            raise Diverged(
                f"Courant number {courant:.4g} exceeds time.max_courant = {self.max_courant:.4g}"
            )
        e = d.get("kinetic_energy")
        growth = tm["max_energy_growth"]
        if e is None:
            return
        ref = max(lp.energy0, lp.energy_peak, self.energy_ref)
        if growth > 0.0 and ref > 0.0 and not e <= growth * ref:
            raise Diverged(
                f"kinetic energy {e:.4g} exceeds time.max_energy_growth = {growth:.4g} x "
                f"{ref:.4g} (the largest of the initial, peak and reference energies)"
            )
        lp.energy_peak = max(lp.energy_peak, e)

    # -- the run ----------------------------------------------------------------
    def run(self) -> RunResult:
        """Set up, step to ``t_end`` with output and diagnostics, write the summary.

        SIGINT / SIGTERM stop the run after the current step with a checkpoint
        (status ``interrupted``, exit code 130 / 143); a second signal stops at once.
        """
        old_handlers = self._install_signals()
        try:
            return self._run()
        finally:
            for sig, h in old_handlers.items():
                signal.signal(sig, h)

    def _run(self) -> RunResult:
        self.setup()
        sc, out, comm = self.scene, self.out, self.comm
        outp = sc["output"]
        resuming = self._resume is not None
        if self.rank0 and not resuming:
            pio.atomic_write_text(out / "scene.toml", sc.resolved_toml())
        tm = sc["time"]
        self.max_courant = tm["max_courant"]
        if self.max_courant is None:
            self.max_courant = 50.0 * tm["courant"] if tm["courant"] is not None else 1000.0
        self.energy_ref = self.solver.energy_scale()
        cloud = self.solver.cloud()
        pw = pio.ParticleWriter(comm, out) if (outp["particles"] and cloud is not None) else None
        if resuming:
            lp = self._load_checkpoint(pw)
            self.say(f"resuming {sc.name} at step {lp.step} (t = {lp.t:.6g}) in {out}")
        else:
            lp = _Loop(dt=self.dt, next_out=outp["every"] if outp["every"] > 0 else math.inf)
        fields = self.solver.fields()
        xdmf = "fields.xdmf" if not resuming else f"fields_resumed_{lp.step}.xdmf"
        fw = (
            pio.FieldWriter(comm, out / xdmf, self.domain.mesh)
            if outp["fields"] and fields
            else None
        )
        csvw = (
            pio.CSVWriter(comm, out / "diagnostics.csv", len(lp.history) if resuming else None)
            if outp["csv"]
            else None
        )
        png_times = sorted(outp["png_times"] or ([] if not outp["png"] else [0.0, tm["t_end"]]))
        every = outp["every"]
        ck_every = outp["checkpoint_every"]
        h_min = self.domain.min_h()
        t_end = tm["t_end"]
        adaptive = bool(tm["adaptive"]) and tm["courant"] is not None
        status, code, message = "ok", EXIT_OK, ""
        cpu0, wall0 = time.process_time(), time.perf_counter()

        def write_outputs(step: int, t: float) -> None:
            lp.last_out = step
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
            while lp.png_i < len(png_times) and (t >= png_times[lp.png_i] - 0.5 * lp.dt or final):
                if outp["png"]:
                    name, u = self.solver.snapshot_field()
                    pio.png_snapshot(
                        out / f"{name}_t{png_times[lp.png_i]:08.3f}.png",
                        u,
                        f"{sc.name}  {name}  {self.solver.time_label(t)}",
                    )
                lp.png_i += 1
                if final:
                    break

        if not resuming:
            d0 = self.solver.diagnostics(0.0)
            d0.update({"step": 0, "t": 0.0})
            lp.history.append(d0)
            lp.energy0 = lp.energy_peak = d0.get("kinetic_energy", 0.0)
            if csvw:
                csvw.write(_row(d0, 0.0, self.solver))
            write_outputs(0, 0.0)
            snapshots(0.0)
        last_good = self.solver.state()

        bar = self._progress(self.steps, lp.step)
        max_steps = tm["max_steps"]
        vmax = self.solver.max_velocity(lp.t)
        try:
            while lp.t < t_end - 1e-12 * max(1.0, t_end):
                t, dt = lp.t, lp.dt
                step = lp.step + 1
                if step > max_steps:
                    raise Diverged(f"time.max_steps = {max_steps} reached at t = {t:.6g}")
                ts = time.perf_counter()
                if adaptive:
                    # Keep the requested Courant number; grow at most 20 % per step, and
                    # split the remainder rather than end on a sliver of a step.
                    if vmax > 0:
                        dt = min(tm["courant"] * h_min / vmax, 1.2 * dt)
                    left = t_end - t
                    dt = left if dt >= left * (1 - 1e-9) else min(dt, 0.5 * left)
                    lp.dt = dt
                courant = vmax * dt / h_min
                self.solver.step(t, dt)
                if adaptive:
                    t = t_end if dt == t_end - t else t + dt
                else:
                    t = step * self.dt if step < self.steps else t_end
                self.solver.check_finite(t)
                vmax = self.solver.max_velocity(t)
                d = self.solver.diagnostics(t)
                d.update({"step": step, "t": t})
                # the Courant number the next step would have with this dt
                self._guard(lp, vmax * dt / h_min, d)
                lp.step, lp.t = step, t
                lp.courant_max = max(lp.courant_max, courant)
                lp.step_wall.append(time.perf_counter() - ts)
                lp.dts.append(dt)
                lp.history.append(d)
                if csvw:
                    csvw.write(_row(d, lp.step_wall[-1], self.solver))
                last_good = self.solver.state()
                lp.t_good = t
                if t >= lp.next_out - 0.5 * dt:
                    write_outputs(step, t)
                    while lp.next_out <= t + 0.5 * dt:
                        lp.next_out += every
                snapshots(t)
                if bar is not None:
                    bar.update(1)
                if self.on_step is not None:
                    self.on_step(self, step, t)
                sig = comm.allreduce(self._signal, op=MPI.MAX)
                if sig or (ck_every > 0 and step % ck_every == 0):
                    lp.wall_before += time.perf_counter() - wall0
                    lp.cpu_before += time.process_time() - cpu0
                    wall0, cpu0 = time.perf_counter(), time.process_time()
                    err = self._write_checkpoint(lp, pw)
                    if err:
                        self.say(f"warning: checkpoint not written: {err}")
                if sig:
                    name = signal.Signals(sig).name
                    status = "interrupted"
                    code = EXIT_SIGINT if sig == signal.SIGINT else EXIT_SIGTERM
                    where = (
                        f"checkpoint in {out / CHECKPOINT}; continue with "
                        f"`pfem2x run --resume {out}`"
                        if not err
                        else f"no checkpoint ({err})"
                    )
                    message = f"interrupted by {name} after step {step} (t = {t:.6g}); {where}"
                    break
        except FloatingPointError as exc:  # Diverged, or a linear solver that diverged
            status, code = "diverged", EXIT_DIVERGED
            step, t_good, dt = lp.step + 1, lp.t_good, lp.dt
            message = (
                f"diverged in step {step} (t = {t_good:.6g} -> {t_good + dt:.6g}, "
                f"{self.solver.time_label(t_good + dt)}): {exc}"
            )
            self._write_last_good(last_good, t_good)
        finally:
            if bar is not None:
                bar.close()
        if status == "ok":
            if lp.last_out != lp.step:
                write_outputs(lp.step, lp.t)
            snapshots(lp.t, final=True)
        if fw:
            fw.close()
        if csvw:
            csvw.close()
        history, dts, step_wall = lp.history, lp.dts, lp.step_wall
        wall = lp.wall_before + time.perf_counter() - wall0
        cpu = comm.allreduce(lp.cpu_before + time.process_time() - cpu0, op=MPI.SUM)
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
            "t_end": float(lp.t),
            "dt": float(np.max(dts)) if dts else float(lp.dt),
            "dt_min": float(np.min(dts)) if dts else float(lp.dt),
            "adaptive_dt": adaptive,
            "courant_max": float(lp.courant_max),
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
        if resuming:
            summary["resumed_at_step"] = int(self._resume[1]["step"])
        if self.rank0:
            pio.write_json(out / "summary.json", summary)
        if status == "ok":
            self.say(
                f"done: {len(history) - 1} steps, dt = {lp.dt:.4g}, "
                f"Courant max {lp.courant_max:.3g}, {wall:.1f} s -> {out}"
            )
        elif status == "interrupted":
            self.say(f"error: {message}")
        else:
            extra = " and last_good_particles.vtp" if self.solver.cloud() is not None else ""
            self.say(f"error: {message}; last good state in {out / 'last_good.xdmf'}{extra}")
        return RunResult(status, code, out, summary, history)

    def _write_last_good(self, last_good: dict[str, np.ndarray], t_good: float) -> None:
        """Restore the last good state and write it for inspection (collective)."""
        self.solver.restore(last_good)
        lg = pio.FieldWriter(self.comm, self.out / "last_good.xdmf", self.domain.mesh)
        lg.write(self.solver.fields(), t_good)
        lg.close()
        cloud = self.solver.cloud()
        if cloud is not None:
            pos, flds = particle_arrays(cloud)
            allp = self.comm.gather(pos, root=0)
            allf = self.comm.gather(flds, root=0)
            if self.rank0:
                pio.write_vtp(
                    self.out / "last_good_particles.vtp",
                    np.concatenate(allp),
                    {k: np.concatenate([f[k] for f in allf]) for k in flds},
                )

    def _progress(self, total: int, done: int = 0) -> Any:
        if not self.rank0 or self.quiet or os.environ.get("CI") or not sys.stderr.isatty():
            return None
        try:
            from tqdm import tqdm  # noqa: PLC0415
        except ImportError:
            return None
        return tqdm(
            total=total,
            initial=done,
            desc=self.scene.name,
            unit="step",
            file=sys.stderr,
            leave=False,
        )


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


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
