"""Physics: the solvers, one per physics and frame, behind one registry.

``make_solver(scene, domain)`` builds the solver of the scene's
``scene.physics`` and ``method.frame``. The registry maps ``(physics, frame)``
to ``"module:Class"`` and imports the module only when that solver is asked
for (the particle kernels compile with numba; a frame that does not use them
does not pay for them). :func:`register` adds a solver.

==============  ==================  =================================================
physics         frame               solver
==============  ==================  =================================================
``transport``   ``eulerian``        :class:`~pfem2x.physics.transport.eulerian.EulerianTransport`
``transport``   ``characteristic``  :class:`~pfem2x.physics.transport.characteristic.CharacteristicTransport`
``transport``   ``lagrangian``      :class:`~pfem2x.physics.transport.lagrangian.LagrangianTransport`
``flow``        ``eulerian``        :class:`~pfem2x.physics.flow.eulerian.EulerianFlow`
``flow``        ``lagrangian``      :class:`~pfem2x.physics.flow.pfem2.LagrangianFlow`
==============  ==================  =================================================
"""  # noqa: E501

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from pfem2x.scene import SceneError

if TYPE_CHECKING:
    from pfem2x.mesh import Domain
    from pfem2x.physics.base import Solver
    from pfem2x.scene import Scene

__all__ = ["SOLVERS", "make_solver", "register", "solver_class"]

#: ``(physics, frame)`` -> ``"module:Class"`` (or the class, once registered as one)
SOLVERS: dict[tuple[str, str], str | type] = {
    ("transport", "eulerian"): "pfem2x.physics.transport.eulerian:EulerianTransport",
    ("transport", "characteristic"): (
        "pfem2x.physics.transport.characteristic:CharacteristicTransport"
    ),
    ("transport", "lagrangian"): "pfem2x.physics.transport.lagrangian:LagrangianTransport",
    ("flow", "eulerian"): "pfem2x.physics.flow.eulerian:EulerianFlow",
    ("flow", "lagrangian"): "pfem2x.physics.flow.pfem2:LagrangianFlow",
}


def register(physics: str, frame: str, target: str | type) -> None:
    """Add (or replace) the solver of ``(physics, frame)``.

    Parameters
    ----------
    physics, frame
        The ``scene.physics`` and ``method.frame`` values it serves.
    target
        The solver class, or ``"module:Class"`` to import on first use.
    """
    SOLVERS[(physics, frame)] = target


def solver_class(physics: str, frame: str) -> type[Solver]:
    """The solver class of ``(physics, frame)``.

    Raises
    ------
    SceneError
        Naming ``scene.physics`` or ``method.frame`` when there is no such solver.
    """
    target = SOLVERS.get((physics, frame))
    if target is None:
        if not any(p == physics for p, _ in SOLVERS):
            raise SceneError(f"scene.physics: {physics!r} is not available yet")
        raise SceneError(f"method.frame: the {frame!r} {physics} frame is not available yet")
    if isinstance(target, str):
        module, _, name = target.partition(":")
        target = getattr(importlib.import_module(module), name)
        SOLVERS[(physics, frame)] = target
    return target


def make_solver(scene: Scene, domain: Domain) -> Solver:
    """The solver for the scene's physics and frame; only the scene's effects are built."""
    return solver_class(scene.physics, scene.frame)(scene, domain)
