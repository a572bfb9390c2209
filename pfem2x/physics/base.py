"""The small step API every solver exposes to the runner."""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x.compat import MPI
from pfem2x.mesh import Domain
from pfem2x.scene import Scene

__all__ = ["Diverged", "Solver"]


class Diverged(FloatingPointError):
    """The solution stopped being finite or physical; names the quantity."""


class Solver:
    """Base class of pfem2x solvers.

    A solver owns its fields and (optionally) a particle cloud. The runner
    owns time, output and printing: solvers never print.

    Subclasses implement :meth:`step` and may override the others.
    """

    #: short name, e.g. ``"transport-eulerian"``
    name = "solver"

    def __init__(self, scene: Scene, domain: Domain):
        self.scene = scene
        self.domain = domain
        self.comm: MPI.Comm = domain.comm
        #: wall seconds per phase, accumulated (``particles``, ``assembly``, ``solve``)
        self.timings: dict[str, float] = {"particles": 0.0, "assembly": 0.0, "solve": 0.0}

    # -- time stepping ------------------------------------------------------
    def max_velocity(self, t: float) -> float:
        """Largest speed on the mesh at time ``t`` (global); 0 when nothing moves."""
        return 0.0

    def step(self, t: float, dt: float) -> None:
        """Advance the solution from ``t`` to ``t + dt``."""
        raise NotImplementedError

    # -- output -------------------------------------------------------------
    def fields(self) -> dict[str, Any]:
        """Mesh functions to write, by name."""
        return {}

    def snapshot_field(self) -> tuple[str, Any]:
        """``(name, function)`` rendered in PNG snapshots (default: the first field)."""
        return next(iter(self.fields().items()))

    def time_label(self, t: float) -> str:
        """How time ``t`` is shown to users (e.g. in another time unit)."""
        return f"t = {t:.4g}"

    def interfaces(self) -> np.ndarray | None:
        """This rank's interface segments ``(m, 2, 2)``, or ``None`` without an interface."""
        return None

    def cloud(self) -> Any | None:
        """The particle cloud, if the solver has one."""
        return None

    def diagnostics(self, t: float) -> dict[str, float]:
        """Scalar diagnostics at time ``t`` (global values, same on all ranks)."""
        return {}

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        """Summary metrics from the diagnostics history (one dict per step)."""
        return {}

    def check_finite(self, t: float) -> None:
        """Raise :class:`Diverged` if any field holds NaN/Inf (collective)."""
        for name, u in self.fields().items():
            bad = 0 if np.all(np.isfinite(u.x.array)) else 1
            if self.comm.allreduce(bad, op=MPI.MAX):
                raise Diverged(f"field {name} is not finite")

    def state(self) -> dict[str, np.ndarray]:
        """A copy of the mesh field arrays (for the last good state)."""
        return {k: u.x.array.copy() for k, u in self.fields().items()}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Put back arrays from :meth:`state`."""
        for k, u in self.fields().items():
            if k in state:
                u.x.array[:] = state[k]
