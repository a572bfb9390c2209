"""The runner: the time loop, and the hand-offs to its parts.

Time-step control lives in :mod:`pfem2x.timestep`, the divergence guards in
:mod:`pfem2x.guards`, output writers and their schedules in
:mod:`pfem2x.output`, restart checkpoints in :mod:`pfem2x.checkpoint`.
Solvers never print; the runner prints on rank 0 only (and not with ``quiet``).
"""

from __future__ import annotations

import dataclasses
import os
import signal
import sys
import threading
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pfem2x import aot, fem, jit, physics
from pfem2x import output as pout
from pfem2x.checkpoint import (
    CHECKPOINT,
    CHECKPOINT_OLD,
    CHECKPOINT_TMP,
    check_meta,
    digest,
    find_checkpoint,
    load_checkpoint,
    write_checkpoint,
)
from pfem2x.compat import MPI
from pfem2x.expr import ExpressionError
from pfem2x.guards import Guards
from pfem2x.mesh import Domain, MeshError, build_mesh
from pfem2x.output import particle_arrays, prepare_output
from pfem2x.physics.base import Diverged, Solver  # noqa: F401 - Diverged re-exported
from pfem2x.scene import Scene, SceneError, validate
from pfem2x.timestep import make_time_control, time_grid

__all__ = [
    "CHECKPOINT",
    "CHECKPOINT_OLD",
    "CHECKPOINT_TMP",
    "RunResult",
    "Simulation",
    "build_domain",
    "find_checkpoint",
    "make_solver",
    "particle_arrays",
    "prepare_output",
    "time_grid",
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
    m = scene.mesh
    try:
        return build_mesh(
            comm,
            m.kind,
            bounds=m.bounds,
            cells=m.cells,
            diagonal=m.diagonal,
            file=m.file,
            periodic=m.periodic,
            partition=m.partition,
        )
    except MeshError as exc:
        raise SceneError(str(exc)) from None


def make_solver(scene: Scene, domain: Domain) -> Solver:
    """The solver for the scene's physics and frame (the registry in :mod:`pfem2x.physics`).

    An expression that cannot be evaluated on the mesh at set-up is bad input:
    :class:`SceneError` naming its key.
    """
    try:
        return physics.make_solver(scene, domain)
    except ExpressionError as exc:
        raise SceneError(str(exc)) from None


@dataclass
class _Loop:
    """The loop's run state: what a checkpoint stores (``meta["loop"]``) besides the solver's.

    The output schedules' state (``next_out``, ``png_i``, ``last_out``) is
    stored next to it by :class:`~pfem2x.output.Outputs`.
    """

    step: int = 0
    t: float = 0.0
    dt: float = 0.0
    t_good: float = 0.0
    courant_max: float = 0.0
    energy0: float = 0.0
    energy_peak: float = 0.0
    wall_before: float = 0.0
    cpu_before: float = 0.0
    growth: dict[str, float] = field(default_factory=dict)
    dts: list[float] = field(default_factory=list)
    step_wall: list[float] = field(default_factory=list)
    history: list[dict[str, float]] = field(default_factory=list)

    @classmethod
    def from_meta(cls, loop: dict[str, Any], history: list[dict[str, float]]) -> _Loop:
        """The state stored in a checkpoint (keys of other parts ignored)."""
        names = {f.name for f in dataclasses.fields(cls)} - {"history"}
        return cls(**{k: v for k, v in loop.items() if k in names}, history=history)


class Simulation:
    """One run of a scene into an output folder.

    Parameters
    ----------
    scene:
        The validated scene.
    out_dir:
        Output folder (created; see :func:`~pfem2x.output.prepare_output`);
        default ``runs/<scene name>``, which must stay inside ``runs/``.
    comm:
        MPI communicator.
    quiet:
        No progress bar or messages.
    overwrite:
        Replace an existing output folder written by pfem2x.

    Notes
    -----
    :meth:`resume` continues an interrupted run from its checkpoint.
    ``on_step(sim, step, t)``, if set, is called after every completed step.
    :meth:`setup` of a particle frame first loads (or, on a cold cache,
    compiles and announces) the numba kernels: ``compile_seconds`` in the summary.
    """

    def __init__(
        self,
        scene: Scene,
        out_dir: str | os.PathLike | None = None,
        comm: MPI.Comm | None = None,
        quiet: bool = False,
        overwrite: bool = False,
    ):
        self.scene = scene
        self.comm = comm or MPI.COMM_WORLD
        if out_dir is None:
            out_dir = Path("runs") / scene.name
            pout.check_default_out(out_dir, "runs")
        self.out = Path(out_dir)
        self.quiet = quiet
        self.overwrite = overwrite
        self.rank0 = self.comm.rank == 0
        self.on_step: Callable[[Simulation, int, float], None] | None = None
        self._resume: tuple[Path, dict[str, Any]] | None = None
        self._scene_text = ""
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
                else:
                    err = check_meta(*found)
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
        if digest(text) != meta["scene_hash"]:
            raise SceneError(f"{out / 'scene.toml'}: changed since the checkpoint was written")
        try:
            raw = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise SceneError(f"{out / 'scene.toml'}: not valid TOML ({exc})") from None
        scene = validate(raw, source=meta["source"], base_dir=Path(meta["base_dir"]))
        sim = cls(scene, out, comm, quiet=quiet)
        sim._resume = (ck, meta)
        sim._scene_text = text
        return sim

    def say(self, msg: str) -> None:
        """Print on rank 0 unless quiet."""
        if self.rank0 and not self.quiet:
            print(msg, file=sys.stderr, flush=True)

    def setup(self) -> None:
        """Build mesh, solver and time control (SceneError on bad input), then the output folder."""
        wall0 = time.perf_counter()
        self.domain = build_domain(self.scene, self.comm)
        fem.reset_counters()
        self.compile_seconds = 0.0
        if self.scene.frame == "lagrangian":  # the particle frames run numba kernels
            if self.comm.allreduce(aot.active(), op=MPI.LAND):  # compiled ahead of time
                aot.on_numba[:] = [lambda: jit.warm_up(self.say)]  # (should numba run one)
            else:
                self.compile_seconds = jit.warm_up(self.say, comm=self.comm)
        self.solver = make_solver(self.scene, self.domain)
        self.time = make_time_control(self.scene, self.domain, self.solver)
        self.dt, self.steps = self.time.dt, self.time.steps
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
        run_started = time.perf_counter()
        self.setup()
        self._start()
        status, code, message = "ok", EXIT_OK, ""
        lp, ck_every = self.loop, self.scene.output.checkpoint_every
        bar = self._progress(self.time.steps, lp.step)
        self.startup_seconds = pout.startup_seconds(run_started)
        self.startup_timings = dict(self.solver.timings)  # the part of the timings before step 1
        try:
            while not self.time.done(lp.t):
                self._step()
                if bar is not None:
                    bar.update(1)
                if self.on_step is not None:
                    self.on_step(self, lp.step, lp.t)
                sig = self.comm.allreduce(self._signal, op=MPI.MAX)
                err = ""
                if sig or (ck_every > 0 and lp.step % ck_every == 0):
                    err = self._checkpoint()
                if sig:
                    status, code, message = self._interrupted(sig, err)
                    break
        except FloatingPointError as exc:  # Diverged, or a linear solver that diverged
            status, code, message = self._diverged(exc)
        except ExpressionError as exc:  # a scene expression failed at a later time: 1/(t - 1)
            status, code, message = self._diverged(exc)
        finally:
            if bar is not None:
                bar.close()
        with self.solver.timer("output"):
            if status == "ok":
                self.outputs.finish(lp.step, lp.t, lp.dt)
            else:
                self._end_snapshot(status)
            self.outputs.close()
        return self._finish(status, code, message)

    def _end_snapshot(self, status: str) -> None:
        """After an early stop, the next PNG time not reached, drawn from the state at the end.

        After a divergence that is the last good state (restored by :meth:`_diverged`).
        A failure to draw (or a second signal while drawing) is a warning: the run's
        status, message and exit code stand.
        """
        lp = self.loop
        t = lp.t_good if status == "diverged" else lp.t
        try:
            self.outputs.snapshots(t, lp.dt, final=True)
        except (Exception, KeyboardInterrupt) as exc:  # noqa: BLE001 - reported, run continues
            self.say(f"warning: snapshot at the end not drawn: {str(exc) or type(exc).__name__}")

    def _start(self) -> None:
        """The run's state at its first step: new (outputs at t = 0) or from the checkpoint."""
        sc, out, comm = self.scene, self.out, self.comm
        if self._resume is None:
            self._scene_text = sc.resolved_toml()
            if self.rank0:
                pout.pio.atomic_write_text(out / "scene.toml", self._scene_text)
            self.outputs = pout.Outputs(sc, comm, out, self.domain, self.solver)
            self._cpu0, self._wall0 = time.process_time(), time.perf_counter()
            with self.solver.timer("diagnostics"):
                d0 = self.solver.diagnostics(0.0)
            d0.update({"step": 0, "t": 0.0})
            e0 = d0.get("kinetic_energy", 0.0)
            self.loop = _Loop(dt=self.time.dt, energy0=e0, energy_peak=e0, history=[d0])
            with self.solver.timer("output"):
                self.outputs.initial(d0, self.loop.dt)
        else:
            ck, meta = self._resume
            history, err = load_checkpoint(comm, ck, self.solver)
            if err:
                raise SceneError(err)
            fem.COUNTERS.update(meta["operators"])
            self.loop = _Loop.from_meta(meta["loop"], history)
            self.outputs = pout.Outputs(
                sc, comm, out, self.domain, self.solver, int(meta["step"]), len(history)
            )
            self.outputs.load_state(meta["loop"], meta.get("particle_outputs", []))
            self._cpu0, self._wall0 = time.process_time(), time.perf_counter()
            self.say(
                f"resuming {sc.name} at step {self.loop.step} (t = {self.loop.t:.6g}) in {out}"
            )
        self.guards = Guards(sc, self.domain, self.solver, self.loop.history[0])
        self.guards.start(self.loop)
        self.last_good = pout.LastGood(comm, out, self.domain, self.solver)
        self.h_min = self.domain.min_h()
        self._vmax = self.solver.max_velocity(self.loop.t)

    def _step(self) -> None:
        """One step: time control, solve, guards, diagnostics, outputs."""
        lp, tc = self.loop, self.time
        t, step = lp.t, lp.step + 1
        self.guards.before_step(step, t)
        ts = time.perf_counter()
        dt = lp.dt = tc.next_dt(t, lp.dt, self._vmax)
        v_start = self._vmax
        self.solver.step(t, dt)
        t = tc.advance(step, t, dt)
        self.guards.after_solve(t)
        with self.solver.timer("diagnostics"):
            self._vmax = self.solver.max_velocity(t)
            d = self.solver.diagnostics(t)
        d.update({"step": step, "t": t})
        self.guards.after_step(lp, t, dt, self._vmax, d)
        lp.step, lp.t = step, t
        # the step's Courant number as run: the larger speed of its start and its end
        lp.courant_max = max(lp.courant_max, max(v_start, self._vmax) * dt / self.h_min)
        lp.step_wall.append(time.perf_counter() - ts)
        lp.dts.append(dt)
        lp.history.append(d)
        with self.solver.timer("output"):
            self.outputs.after_step(step, t, dt, d, lp.step_wall[-1])
            self.last_good.keep()
            lp.t_good = t
            self.outputs.snapshots(t, dt)

    def _checkpoint(self) -> str:
        """Write a checkpoint (collective); returns an error text or ``""``."""
        lp = self.loop
        lp.wall_before += time.perf_counter() - self._wall0
        lp.cpu_before += time.process_time() - self._cpu0
        self._wall0, self._cpu0 = time.perf_counter(), time.process_time()
        loop = {k: v for k, v in vars(lp).items() if k != "history"}
        loop.update(self.outputs.state())
        extra = {
            "operators": dict(fem.COUNTERS),
            "particle_outputs": self.outputs.particle_entries(),
        }
        err = write_checkpoint(
            self.comm, self.out, self.solver, self.scene, self._scene_text, loop, lp.history, extra
        )
        if err:
            self.say(f"warning: checkpoint not written: {err}")
        return err

    def _interrupted(self, sig: int, err: str) -> tuple[str, int, str]:
        lp = self.loop
        where = (
            f"checkpoint in {self.out / CHECKPOINT}; continue with `pfem2x run --resume {self.out}`"
            if not err
            else f"no checkpoint ({err})"
        )
        code = EXIT_SIGINT if sig == signal.SIGINT else EXIT_SIGTERM
        name = signal.Signals(sig).name
        return (
            "interrupted",
            code,
            f"interrupted by {name} after step {lp.step} (t = {lp.t:.6g}); {where}",
        )

    def _diverged(self, exc: Exception) -> tuple[str, int, str]:
        lp = self.loop
        t_good, dt = lp.t_good, lp.dt
        message = (
            f"diverged in step {lp.step + 1} (t = {t_good:.6g} -> {t_good + dt:.6g}, "
            f"{self.solver.time_label(t_good + dt)}): {exc}"
        )
        if not isinstance(exc, ExpressionError):  # (that one names its key already)
            culprit = self.solver.input_report(t_good, t_good + dt)
            if culprit:
                message += f" ({culprit})"
        self.last_good.write(t_good)
        return "diverged", EXIT_DIVERGED, message

    def _finish(self, status: str, code: int, message: str) -> RunResult:
        """Write ``summary.json``, report, and return the result."""
        lp, out = self.loop, self.out
        wall = lp.wall_before + time.perf_counter() - self._wall0
        run = {
            "status": status,
            "message": message,
            "history": lp.history,
            "dts": lp.dts,
            "step_wall": lp.step_wall,
            "t": lp.t,
            "dt": lp.dt,
            "courant_max": lp.courant_max,
            "adaptive": self.time.adaptive,
            "wall": wall,
            "cpu": lp.cpu_before + time.process_time() - self._cpu0,
            "setup_seconds": self.setup_seconds,
            "startup_seconds": self.startup_seconds,
            "startup_timings": self.startup_timings,
            "compile_seconds": self.comm.allreduce(self.compile_seconds, op=MPI.MAX),
        }
        summary = pout.summary(self.scene, self.comm, self.domain, self.solver, run)
        if self._resume is not None:
            summary["resumed_at_step"] = int(self._resume[1]["step"])
        err = ""
        if self.rank0:
            try:
                pout.pio.write_json(out / "summary.json", summary)
            except OSError as exc:
                err = f"{out / 'summary.json'}: {exc.strerror or exc}"
        # every rank returns once the files are on disk (scripts read them after run())
        err = self.comm.bcast(err, root=0)
        if err:
            self.say(f"warning: summary not written: {err}")
        steps = len(lp.history) - 1
        if status == "ok":
            lo, hi = (min(lp.dts), max(lp.dts)) if lp.dts else (lp.dt, lp.dt)
            dts = f"dt = {hi:.4g}" if lo == hi else f"dt = {lo:.4g} to {hi:.4g}"
            self.say(
                f"done: {steps} steps, {dts}, Courant max {lp.courant_max:.3g}, "
                f"{wall:.1f} s -> {out}"
            )
        elif status == "interrupted":
            self.say(f"error: {message}")
        else:
            self.say(f"error: {message}; last good state in {self.last_good.where()}")
        return RunResult(status, code, out, summary, lp.history)

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
