"""Open box sides of the PFEM-2 flow frame: ``inflow`` and ``outflow`` (one phase).

A mixin of :class:`~pfem2x.physics.flow.pfem2.LagrangianFlow` (its attributes:
``cloud_``, ``domain``, ``gdim``, ``problem``, ``scene``, ``b_m``, ``a_K``,
``_bcs_u``, ``_inflow``, ``_t_next``, ``_inflow_seed``).

Particles that leave through an ``outflow`` side are deleted in the move (the
cloud's outflow facets, :func:`_sides`); after each move the cells on an ``inflow``
side are topped up to ``method.particles_per_cell`` with particles carrying
``flow.inflow_velocity`` (:meth:`OpenSides._seed_inflow`), and so are the cells within
one step's inflow travel of it (:meth:`OpenSides._inflow_band`), where the particles whose
path of the step came in through the side take the inflow velocity where it crossed plus
the step's source (:meth:`OpenSides._trace_inflow`); the viscous predictor's right-hand
side lifts the inflow values through its operator (:meth:`OpenSides._set_viscous_bc`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x import particles as P
from pfem2x.compat import MPI
from pfem2x.scene import FLOW_SIDES

__all__ = ["OpenSides"]


class OpenSides:
    """Inflow seeding, outflow markers and the lifted viscous right-hand side."""

    cloud_: Any
    domain: Any
    gdim: int
    problem: Any
    scene: Any
    b_m: Any
    a_K: Any
    _bcs_u: list
    _inflow: Any
    #: ``flow.inflow_velocity`` at points and a time (:meth:`FlowSolver.inflow_at`)
    inflow_at: Any
    #: the nodes of the inflow sides (:meth:`FlowSolver._boundary_conditions`)
    _inflow_nodes: np.ndarray
    #: the end of the current step (the inflow values of new particles)
    _t_next: float = 0.0
    #: inflow seedings so far (their random seeds)
    _inflow_seed: int = 0
    #: the current step
    _dt_step: float = 0.0
    comm: Any
    H: float
    cell_xy: np.ndarray
    u: Any
    force: Any

    def _planes(self, kind: str) -> list[tuple[int, float]]:
        """``(axis, coordinate)`` of each box side of ``kind`` (``inflow``, ``outflow``)."""
        lo, hi = self.domain.bounds
        return [
            (k // 2, (lo if k % 2 == 0 else hi)[k // 2])
            for k, side in enumerate(FLOW_SIDES[: 2 * self.gdim])
            if self.problem.sides[side] == kind
        ]

    def _sides(self, kind: str) -> Any:
        """A facet marker of the box sides of ``kind`` (``inflow``, ``outflow``), or None."""
        lo, hi = self.domain.bounds
        tol = 1e-8 * float(np.max(hi - lo))
        sel = self._planes(kind)
        if not sel:
            return None
        return lambda x: np.any([np.abs(x[:, a] - v) < tol for a, v in sel], axis=0)

    def _seed_inflow(self) -> None:
        """Cells on inflow sides topped up to ``particles_per_cell`` with the inflow velocity.

        The new particles take ``flow.inflow_velocity`` at their positions and the end
        of the step (``_t_next``); the move has carried the old ones inwards.
        """
        if self._inflow is None:
            return
        t = self._t_next

        def u_in(x: np.ndarray) -> np.ndarray:
            x3 = np.zeros((len(x), 3))
            x3[:, : self.gdim] = x
            return self.inflow_at(x3, t)

        self._inflow_seed += 1
        ppc, seed = self.scene.method.particles_per_cell, self.scene.method.seed
        P.seed_inflow(self.cloud_, ppc, {"u": u_in}, seed=seed + 7919 * self._inflow_seed)
        band = self._inflow_band()
        if band is not None:
            P.rebalance(
                self.cloud_, ppc, 0, seed=seed + 7919 * self._inflow_seed + 1,
                fallback={"u": self.u}, cells=band,
            )  # fmt: skip
            self._trace_inflow(band, u_in)

    def _trace_inflow(self, band: np.ndarray, u_in: Any) -> None:
        """Particles of the band whose path of this step came in through an inflow side.

        A particle at ``x`` with velocity ``u`` whose straight path back over the step
        crosses an inflow side (inward normal speed ``u_n > 0``, distance ``d < u_n dt``)
        entered during the step: it takes the inflow velocity where that path crosses
        the side, found by two fixed-point updates of ``u`` (exact for a parallel
        inflow), plus the whole step's explicit source ``a`` at its position, as the
        particle it stands for (upstream of the side at the start of the step, with the
        inflow's state) would have: the viscous predictor acts on the nodes over the
        whole step, so the explicit part must too (they cancel in a developed flow; with
        the source only since the crossing a channel at Courant 8 lost ``(dt - d/u_n) G``
        behind the inflow). The values of the band's new particles are otherwise fits of
        their neighbours', whose repeated re-fitting would smooth the inflow profile.
        """
        c = self.cloud_
        sel = np.flatnonzero(band[c.cells])
        if len(sel) == 0:
            return
        x, u = c.x[sel], c.field("u")[sel]
        acc = P.evaluate(c, self.force, sel)  # the explicit source
        lo = self.domain.bounds[0]
        for a, v in self._planes("inflow"):
            inward = 1.0 if v == lo[a] else -1.0
            d = (x[:, a] - v) * inward
            vals = u.copy()
            for _ in range(2):
                un = np.maximum(vals[:, a] * inward, 1e-300)
                foot = x - vals * (d / un)[:, None]
                foot[:, a] = v
                vals = u_in(foot)
            un = vals[:, a] * inward
            hit = (un > 0.0) & (d < un * self._dt_step)
            u[hit] = vals[hit] + self._dt_step * acc[hit]
        c.field("u")[sel] = u

    def _inflow_band(self) -> np.ndarray | None:
        """Owned cells within one step's inflow travel of an inflow side (a bool mask).

        The cells behind the first layer that the particles of the inflow have crossed
        in this step (the largest inflow speed times the step, plus a cell); None
        when the band is the first layer only.
        """
        # (the inflow sides' nodes: the expression is evaluated everywhere, used there)
        u_in = self._inflow.x.array.reshape(-1, self.gdim)[self._inflow_nodes]
        reach = float(np.sqrt((u_in**2).sum(axis=1)).max(initial=0.0)) * self._dt_step
        reach = float(self.comm.allreduce(reach, op=MPI.MAX))
        if reach <= self.H:
            return None
        centre = self.cell_xy.mean(axis=1)
        band = np.zeros(len(centre), dtype=bool)
        for a, v in self._planes("inflow"):
            band |= np.abs(centre[:, a] - v) < reach + self.H
        return band

    def _set_viscous_bc(self) -> None:
        """The Dirichlet values into ``b_m`` (lifted through ``K`` with an inflow side)."""
        if self._inflow is not None:
            compat.lift(self.b_m, self.a_K, self._bcs_u)
        compat.set_bc(self.b_m, self._bcs_u)
