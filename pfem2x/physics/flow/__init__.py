"""Incompressible Navier–Stokes, one or two phases, on the fixed P1/P1 mesh.

- :mod:`~pfem2x.physics.flow.problem`: scene data, spaces, boundaries, diagnostics;
- :mod:`~pfem2x.physics.flow.projection`: the pressure step;
- :mod:`~pfem2x.physics.flow.interface`: level-set geometry (cut segments,
  distances, re-distancing);
- the frames: :mod:`~pfem2x.physics.flow.eulerian` (level set, the baseline) and
  :mod:`~pfem2x.physics.flow.pfem2` (PFEM-2 particles).
"""

from __future__ import annotations

from pfem2x.physics.flow.eulerian import EulerianFlow
from pfem2x.physics.flow.interface import cut_segments, positive_fraction, segment_distance
from pfem2x.physics.flow.problem import FlowProblem, FlowSolver

__all__ = [
    "EulerianFlow",
    "FlowProblem",
    "FlowSolver",
    "cut_segments",
    "positive_fraction",
    "segment_distance",
]
