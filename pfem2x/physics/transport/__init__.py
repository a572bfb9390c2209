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

from typing import TYPE_CHECKING, Any

from pfem2x.physics import solver_class
from pfem2x.physics.transport.characteristic import CharacteristicTransport
from pfem2x.physics.transport.eulerian import EulerianTransport
from pfem2x.physics.transport.problem import TransportBase, TransportProblem

if TYPE_CHECKING:
    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = [
    "CharacteristicTransport",
    "EulerianTransport",
    "LagrangianTransport",
    "TransportBase",
    "TransportProblem",
    "make_transport_solver",
]


def make_transport_solver(scene: Scene, domain: Domain) -> Solver:
    """The transport solver of the scene's frame (see :func:`pfem2x.physics.make_solver`)."""
    return solver_class("transport", scene.frame)(scene, domain)


def __getattr__(name: str) -> Any:
    if name == "LagrangianTransport":  # imported on demand: it compiles the particle kernels
        from pfem2x.physics.transport.lagrangian import LagrangianTransport  # noqa: PLC0415

        return LagrangianTransport
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
