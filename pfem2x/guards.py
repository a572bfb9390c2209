"""Divergence guards: each checks one quantity and raises :class:`Diverged` naming it.

The runner calls :meth:`Guards.before_step` before a step and
:meth:`Guards.after_step` once the step's diagnostics are known; a raise
there is the ``diverged`` status (exit 3, last good state written). Every
check is collective or on global values, so all ranks raise together.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from pfem2x.compat import MPI
from pfem2x.physics.base import Diverged

if TYPE_CHECKING:
    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = [
    "CourantGuard",
    "EnergyGuard",
    "FiniteGuard",
    "Guards",
    "MaxStepsGuard",
    "TransportGrowthGuard",
]


class MaxStepsGuard:
    """``time.max_steps``: no step beyond it."""

    def __init__(self, max_steps: int):
        self.max_steps = max_steps

    def before_step(self, step: int, t: float) -> None:
        """Raise before step number ``step`` (taken from ``t``) if it is one too many."""
        if step > self.max_steps:
            raise Diverged(f"time.max_steps = {self.max_steps} reached at t = {t:.6g}")


class FiniteGuard:
    """Every field (and the particles) finite: the solver's own collective check."""

    def __init__(self, solver: Solver):
        self.solver = solver

    def after_solve(self, t: float) -> None:
        """Raise if a field is not finite at ``t``."""
        self.solver.check_finite(t)


class CourantGuard:
    """A Courant number above ``time.max_courant`` (max|V| after the step x dt / H)."""

    def __init__(self, max_courant: float):
        self.max_courant = max_courant

    def check(self, courant: float) -> None:
        """Raise when ``courant`` exceeds the limit (a limit of 0: off)."""
        if 0.0 < self.max_courant < courant:
            raise Diverged(
                f"Courant number {courant:.4g} exceeds time.max_courant = {self.max_courant:.4g}"
            )


class EnergyGuard:
    """Kinetic energy above ``time.max_energy_growth`` x max(initial, peak, reference).

    The initial and peak energies live in the loop state (``energy0``,
    ``energy_peak``) so that they survive a checkpoint.
    """

    def __init__(self, growth: float, reference: float):
        self.growth, self.reference = growth, reference

    def check(self, loop: Any, d: dict[str, float]) -> None:
        """Check the step's diagnostics ``d``; update ``loop.energy_peak``."""
        e = d.get("kinetic_energy")
        if e is None:
            return
        ref = max(loop.energy0, loop.energy_peak, self.reference)
        if self.growth > 0.0 and ref > 0.0 and not e <= self.growth * ref:
            raise Diverged(
                f"kinetic energy {e:.4g} exceeds time.max_energy_growth = {self.growth:.4g} x "
                f"{ref:.4g} (the largest of the initial, peak and reference energies)"
            )
        loop.energy_peak = max(loop.energy_peak, e)


class TransportGrowthGuard:
    r"""A transported field beyond ``time.max_growth`` x its maximum-principle bound.

    For :math:`T_t + V\cdot\nabla T = \nabla\cdot\kappa\nabla T - cT + q` with
    Dirichlet data :math:`g` the maximum principle gives

    .. math:: \|T(t)\|_\infty \le e^{\int_0^t c_-}\,\big(\max(\|T_0\|_\infty,
              \sup_{s\le t}\|g(s)\|_\infty) + \int_0^t \|q(s)\|_\infty\,ds\big),

    :math:`c_- = \max(0, -\min c)`. The data are evaluated at the mesh nodes
    at the end of every step; the integrals use the larger end value of the
    step (the bound grows monotonically). The run state (``loop.growth``:
    source integral, reaction exponent, max|g|) is stored in checkpoints.
    A bound of 0 (all data zero) is not checked.
    """

    def __init__(self, scene: Scene, domain: Domain, factor: float, t0_abs: float):
        eff, tr = scene.effects, scene.transport
        self.factor = factor
        self.field = tr.field
        self.t0_abs = t0_abs
        self.x = np.asarray(domain.mesh.geometry.x)
        self.comm = domain.comm
        self.source = scene.expr("transport", "source") if eff.source else None
        self.reaction = scene.expr("transport", "reaction") if eff.reaction else None
        self.boundary = (
            scene.expr("transport", "boundary_value") if tr.boundary_value is not None else None
        )

    def _data(self, t: float) -> tuple[float, float, float]:
        """Global ``(max|q|, max(0, -min c), max|g|)`` at time ``t`` (collective)."""

        def amax(e: Any, sign: float = 0.0) -> float:
            if e is None or len(self.x) == 0:
                return 0.0
            v = e(self.x, t)
            return float(np.max(np.abs(v))) if sign == 0.0 else max(0.0, float(np.max(-v)))

        local = np.array([amax(self.source), amax(self.reaction, -1.0), amax(self.boundary)])
        glob = np.empty_like(local)
        self.comm.Allreduce(local, glob, op=MPI.MAX)
        return float(glob[0]), float(glob[1]), float(glob[2])

    def start(self, loop: Any, t: float) -> None:
        """Initialise ``loop.growth`` at ``t`` (a new run, or a checkpoint without it)."""
        q, c, g = self._data(t)
        loop.growth = {"t": t, "q": q, "c": c, "q_int": 0.0, "c_int": 0.0, "g_max": g}

    def check(self, loop: Any, t: float, d: dict[str, float]) -> None:
        """Check ``max|T|`` of the step's diagnostics ``d`` at ``t``; update ``loop.growth``."""
        if self.factor <= 0.0 or "max" not in d:
            return
        s = loop.growth
        q, c, g = self._data(t)
        dt = t - s["t"]
        s["q_int"] += dt * max(q, s["q"])
        s["c_int"] += dt * max(c, s["c"])
        s["g_max"] = max(s["g_max"], g)
        s.update(t=t, q=q, c=c)
        bound = math.exp(min(s["c_int"], 700.0)) * (max(self.t0_abs, s["g_max"]) + s["q_int"])
        val = max(abs(d["max"]), abs(d["min"]))
        if bound > 0.0 and not val <= self.factor * bound:
            raise Diverged(
                f"field {self.field}: max|{self.field}| = {val:.4g} exceeds time.max_growth = "
                f"{self.factor:.4g} x {bound:.4g} (the maximum-principle bound from the "
                f"initial, boundary, source and reaction data)"
            )


class Guards:
    """The guards of one run, called by the loop.

    Parameters
    ----------
    scene, domain, solver:
        The run's scene, mesh and solver.
    d0:
        The diagnostics at ``t = 0`` (initial field range of the growth guard).
    """

    def __init__(self, scene: Scene, domain: Domain, solver: Solver, d0: dict[str, float]):
        tm = scene.time
        max_courant = tm.max_courant
        if max_courant is None:
            max_courant = 50.0 * tm.courant if tm.courant is not None else 1000.0
        self.h_min = domain.min_h()
        self.steps = MaxStepsGuard(tm.max_steps)
        self.finite = FiniteGuard(solver)
        self.courant = CourantGuard(max_courant)
        self.energy = EnergyGuard(tm.max_energy_growth, solver.energy_scale())
        self.growth = None
        if scene.physics == "transport" and tm.max_growth > 0.0:
            t0 = max(abs(d0.get("max", 0.0)), abs(d0.get("min", 0.0)))
            self.growth = TransportGrowthGuard(scene, domain, tm.max_growth, t0)

    def start(self, loop: Any) -> None:
        """Initialise the guards' loop state if it lacks it (a new run, an old checkpoint)."""
        if self.growth is not None and not loop.growth:
            self.growth.start(loop, loop.t)

    def before_step(self, step: int, t: float) -> None:
        """Before step number ``step`` from ``t``."""
        self.steps.before_step(step, t)

    def after_solve(self, t: float) -> None:
        """Right after the solve, before diagnostics."""
        self.finite.after_solve(t)

    def after_step(self, loop: Any, t: float, dt: float, vmax: float, d: dict[str, float]) -> None:
        """After the step's diagnostics ``d`` at ``t``; ``vmax``: max|V| at ``t``."""
        # the Courant number the next step would have with this dt
        self.courant.check(vmax * dt / self.h_min)
        self.energy.check(loop, d)
        if self.growth is not None:
            self.growth.check(loop, t, d)
