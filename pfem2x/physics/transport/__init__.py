r"""Scalar transport :math:`\partial_t T + V\cdot\nabla T = q + \nabla\cdot(\kappa\nabla T) - cT`.

Each term is present only if the scene's ``[effects]`` list it
(``advection``, ``diffusion``, ``source``, ``reaction``). Frames:

- ``eulerian`` (:mod:`~pfem2x.physics.transport.eulerian`): P1 Galerkin,
  θ-method (``method.theta``), consistent mass, optional SUPG (``method.supg``).
- ``characteristic`` (:mod:`~pfem2x.physics.transport.characteristic`):
  characteristic Galerkin, the paper's single-mesh Lagrangian comparator (one
  "particle" per node): every node is traced back along the velocity to its
  foot, ``T^n`` is interpolated there, the source is integrated along the path
  (eq. 2.9); diffusion/reaction implicitly on the mesh.
- ``lagrangian`` (:mod:`~pfem2x.physics.transport.lagrangian`): PFEM-2 (paper
  section 3, steps 0-6) on the particle layer.

What they share is in :mod:`~pfem2x.physics.transport.problem` and
:mod:`~pfem2x.physics.transport.implicit`. Periodic meshes (``mesh.periodic``)
are supported in every mesh solve through :class:`pfem2x.periodic.PeriodicConstraint`.
"""

from __future__ import annotations

from pfem2x.physics.transport.characteristic import CharacteristicTransport
from pfem2x.physics.transport.eulerian import EulerianTransport
from pfem2x.physics.transport.problem import TransportBase, TransportProblem

__all__ = [
    "CharacteristicTransport",
    "EulerianTransport",
    "TransportBase",
    "TransportProblem",
]
