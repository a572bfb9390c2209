"""Time-step control: a fixed step, a step from the Courant number, an adaptive step.

Each control gives the next ``dt`` (:meth:`TimeControl.next_dt`) and the
time reached after a step (:meth:`TimeControl.advance`); the runner owns the
loop.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from pfem2x.expr import ExpressionError
from pfem2x.scene import Scene, SceneError

if TYPE_CHECKING:
    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver

__all__ = ["AdaptiveStep", "TimeControl", "UniformStep", "make_time_control", "time_grid"]


def time_grid(scene: Scene, domain: Domain, solver: Solver) -> tuple[float, int]:
    """``(dt, steps)``: a uniform step landing exactly on ``t_end``.

    ``time.dt`` as given, or ``time.courant`` x H / max|V(x, 0)|; refuses
    (:class:`SceneError`) a zero velocity with ``time.courant`` and more
    steps than ``time.max_steps``.
    """
    t_end = scene.time.t_end
    dt = scene.time.dt
    if dt is None:
        try:
            vmax = solver.max_velocity(0.0)
        except ExpressionError as exc:
            raise SceneError(str(exc)) from None
        if vmax <= 0.0:
            raise SceneError("time.courant: the velocity is zero at t = 0; give time.dt instead")
        dt = scene.time.courant * domain.min_h() / vmax
    n = t_end / dt
    if not n <= scene.time.max_steps:  # (compared as a float: a tiny step gives 1e300 steps)
        key = "time.dt" if scene.time.dt is not None else "time.courant"
        raise SceneError(
            f"{key}: {n:.3g} steps to time.t_end exceed time.max_steps = {scene.time.max_steps}"
        )
    steps = max(1, math.ceil(n - 1e-9))
    return t_end / steps, steps


class TimeControl:
    """The time-step policy of a run.

    Parameters
    ----------
    dt:
        The first (planned) step.
    steps:
        The planned number of steps (progress bar; exact for uniform steps).
    t_end:
        The end time.
    """

    adaptive = False

    def __init__(self, dt: float, steps: int, t_end: float):
        self.dt, self.steps, self.t_end = dt, steps, t_end

    def done(self, t: float) -> bool:
        """Whether ``t`` is the end time (to round-off)."""
        return not t < self.t_end - 1e-12 * max(1.0, self.t_end)

    def next_dt(self, t: float, dt: float, vmax: float) -> float:
        """The step to take from ``t``, given the previous step ``dt`` and max|V| at ``t``."""
        return dt

    def advance(self, step: int, t: float, dt: float) -> float:
        """The time reached by step number ``step`` of size ``dt`` taken from ``t``."""
        raise NotImplementedError


class UniformStep(TimeControl):
    """``steps`` equal steps landing exactly on ``t_end`` (``time.dt`` or ``time.courant``)."""

    def advance(self, step: int, t: float, dt: float) -> float:
        return step * self.dt if step < self.steps else self.t_end


class AdaptiveStep(TimeControl):
    """Re-evaluated every step to keep ``courant`` (``time.adaptive``).

    Grows at most 20 % per step, and splits the remainder rather than end on
    a sliver of a step.
    """

    adaptive = True

    def __init__(self, dt: float, steps: int, t_end: float, courant: float, h_min: float):
        super().__init__(dt, steps, t_end)
        self.courant, self.h_min = courant, h_min

    def next_dt(self, t: float, dt: float, vmax: float) -> float:
        if vmax > 0:
            dt = min(self.courant * self.h_min / vmax, 1.2 * dt)
        left = self.t_end - t
        return left if dt >= left * (1 - 1e-9) else min(dt, 0.5 * left)

    def advance(self, step: int, t: float, dt: float) -> float:
        return self.t_end if dt == self.t_end - t else t + dt


def make_time_control(scene: Scene, domain: Domain, solver: Solver) -> TimeControl:
    """The scene's time control (:class:`SceneError` on an impossible plan)."""
    tm = scene.time
    dt, steps = time_grid(scene, domain, solver)
    if tm.adaptive and tm.courant is not None:
        return AdaptiveStep(dt, steps, tm.t_end, tm.courant, domain.min_h())
    return UniformStep(dt, steps, tm.t_end)
