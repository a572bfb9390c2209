r"""Flow errors against an exact solution: ``flow.exact_velocity``, ``flow.exact_pressure``.

The norm is the domain RMS of the error, as ``l2_error`` of the transport
frames:

.. math::
    e_u = \frac{\lVert u_h - u \rVert_{L^2(\Omega)}}{\sqrt{|\Omega|}}, \qquad
    e_p = \frac{\lVert (p_h - \bar p_h) - (p - \bar p) \rVert_{L^2(\Omega)}}{\sqrt{|\Omega|}},

where :math:`\bar f` is the mean of :math:`f` over :math:`\Omega`: the pressure
of a box without a pressure condition is defined up to a constant, so both
pressures are compared after removing their means.

The integrals are a tensor Gauss rule on the collapsed triangle (Duffy), exact
for polynomials of degree :attr:`ExactFlowError.DEGREE` on each cell, with the
exact expression evaluated at the quadrature points (not interpolated into P1
first: that interpolation error would be of the size of the discretisation
error being measured). The discrete fields are P1, so they are exact at the
quadrature points.
"""

from __future__ import annotations

import numpy as np

from pfem2x import fem
from pfem2x.compat import MPI
from pfem2x.expr import Expression

__all__ = ["ExactFlowError", "triangle_quadrature"]


def triangle_quadrature(degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric points ``(m, 3)`` and weights ``(m,)`` (summing to 1) on a triangle.

    The collapsed-square (Duffy) Gauss–Legendre rule with ``n = ceil((degree + 2) / 2)``
    points per direction: exact for polynomials of total degree ``degree``.

    Parameters
    ----------
    degree:
        Polynomial degree integrated exactly (>= 0).
    """
    n = max(1, int(np.ceil((degree + 2) / 2)))
    g, w = np.polynomial.legendre.leggauss(n)
    a, wa = 0.5 * (g + 1.0), 0.5 * w  # on [0, 1]
    A, B = np.meshgrid(a, a, indexing="ij")
    W = np.outer(wa, wa) * (1.0 - A)  # Jacobian of (a, b) -> (a, b (1 - a))
    xi, eta = A.ravel(), (B * (1.0 - A)).ravel()
    lam = np.stack([1.0 - xi - eta, xi, eta], axis=1)
    return lam, 2.0 * W.ravel()  # the reference triangle's area is 1/2


class ExactFlowError:
    """Domain-RMS errors of the P1 velocity and pressure against exact expressions.

    Parameters
    ----------
    comm:
        The mesh communicator (every method is collective).
    cell_xy:
        Vertex coordinates of the owned cells, ``(n, 3, gdim)``, ordered like ``dofmap``.
    cell_vol:
        Their areas ``(n,)``.
    dofmap:
        Owned cell → P1 dof table ``(n, 3)``.
    velocity, pressure:
        Exact component expressions (``gdim`` of them) and exact pressure, or ``None``.
    """

    #: Polynomial degree the quadrature integrates exactly.
    DEGREE = 6

    def __init__(
        self,
        comm: MPI.Comm,
        cell_xy: np.ndarray,
        cell_vol: np.ndarray,
        dofmap: np.ndarray,
        velocity: list[Expression] | None,
        pressure: Expression | None,
    ):
        self.comm = comm
        self.velocity = velocity
        self.pressure = pressure
        self.dofmap = dofmap
        self.lam, w = triangle_quadrature(self.DEGREE)
        n, nq = len(cell_vol), len(w)
        self.weights = (cell_vol[:, None] * w[None, :]).reshape(n * nq)  # (n nq,)
        gdim = cell_xy.shape[2]
        pts = np.einsum("qk,ckd->cqd", self.lam, cell_xy).reshape(n * nq, gdim)
        self.points = np.zeros((n * nq, 3))
        self.points[:, :gdim] = pts
        self.volume = self._sum(np.ones(n * nq))  # |Omega|, as the rule integrates 1

    def _at_points(self, nodal: np.ndarray) -> np.ndarray:
        """P1 nodal values ``(ndofs, k)`` at the quadrature points: ``(n nq, k)``."""
        vals = nodal[self.dofmap]  # (n, 3, k)
        return np.einsum("qk,ckj->cqj", self.lam, vals).reshape(-1, nodal.shape[1])

    def _sum(self, v: np.ndarray) -> float:
        return float(self.comm.allreduce(float(np.dot(self.weights, v)), op=MPI.SUM))

    def velocity_error(self, u: np.ndarray, t: float) -> float:
        """The domain-RMS velocity error at time ``t``; ``u``: nodal values ``(ndofs, gdim)``."""
        uq = self._at_points(u)
        for i, e in enumerate(self.velocity):
            uq[:, i] -= e(self.points, t)
        return float(np.sqrt(max(self._sum(np.sum(uq**2, axis=1)), 0.0) / self.volume))

    def pressure_error(self, p: np.ndarray, t: float) -> float:
        """The domain-RMS error of the pressure after removing both means; ``p``: ``(ndofs,)``."""
        diff = self._at_points(p[:, None])[:, 0] - self.pressure(self.points, t)
        for _ in range(2):  # mean(p_h) - mean(p), subtracted (twice: round-off of a big mean)
            diff -= self._sum(diff) / self.volume
        return float(np.sqrt(max(self._sum(diff**2), 0.0) / self.volume))

    def diagnostics(self, u: np.ndarray, p: np.ndarray, t: float) -> dict[str, float]:
        """``velocity_l2_error`` and / or ``pressure_l2_error`` (those with an exact field)."""
        fem.COUNTERS["error_integrals"] += 1
        out = {}
        if self.velocity is not None:
            out["velocity_l2_error"] = self.velocity_error(u, t)
        if self.pressure is not None:
            out["pressure_l2_error"] = self.pressure_error(p, t)
        return out

    @staticmethod
    def metrics(history: list[dict[str, float]]) -> dict[str, float]:
        """``<name>_time_avg``, ``_final`` and ``_max`` of every error column in ``history``."""
        out = {}
        for name in ("velocity_l2_error", "pressure_l2_error"):
            errs = [h[name] for h in history if name in h]
            if errs:
                out[f"{name}_time_avg"] = float(np.mean(errs))
                out[f"{name}_final"] = float(errs[-1])
                out[f"{name}_max"] = float(np.max(errs))
        return out
