"""Incompressible Navier–Stokes, one or two phases, on the fixed P1/P1 mesh.

- :mod:`~pfem2x.physics.flow.problem`: scene data, spaces, boundaries, diagnostics;
- :mod:`~pfem2x.physics.flow.projection`: the pressure step;
- :mod:`~pfem2x.physics.flow.interface`: level-set geometry (cut segments,
  distances, re-distancing);
- the frames: :mod:`~pfem2x.physics.flow.eulerian` (level set, the baseline) and
  :mod:`~pfem2x.physics.flow.pfem2` (PFEM-2 particles).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pfem2x.physics import solver_class
from pfem2x.physics.flow.eulerian import EulerianFlow
from pfem2x.physics.flow.interface import cut_segments, positive_fraction, segment_distance
from pfem2x.physics.flow.problem import FlowProblem, FlowSolver

if TYPE_CHECKING:
    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = [
    "EulerianFlow",
    "FlowProblem",
    "FlowSolver",
    "cut_segments",
    "make_flow_solver",
    "positive_fraction",
    "segment_distance",
]


def make_flow_solver(scene: Scene, domain: Domain) -> Solver:
    """The flow solver of the scene's frame (see :func:`pfem2x.physics.make_solver`)."""
    return solver_class("flow", scene.frame)(scene, domain)


def __getattr__(name: str) -> Any:
    if name == "LagrangianFlow":  # imported on demand: it compiles the particle kernels
        from pfem2x.physics.flow.pfem2 import LagrangianFlow  # noqa: PLC0415

        return LagrangianFlow
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
