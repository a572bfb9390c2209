"""Path integration of points along a prescribed velocity (vectorised over points).

Used by the characteristic frame (tracing mesh nodes back to their feet) and
by the Lagrangian frame when a path integral of the source is needed. The
velocity is the scene's expression, evaluated at the points (for the linear
velocity fields of the paper's cases this equals its P1 interpolant).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Box", "PathResult", "trace"]


@dataclass
class Box:
    """The domain's bounding box: periodic axes wrap, the others are closed.

    Attributes
    ----------
    lo, hi:
        ``(gdim,)`` corners.
    periodic:
        ``(gdim,)`` bool.
    """

    lo: np.ndarray
    hi: np.ndarray
    periodic: np.ndarray

    def wrap(self, x: np.ndarray) -> np.ndarray:
        """Map points into ``[lo, hi)`` along the periodic axes (in place; returned)."""
        for ax in np.flatnonzero(self.periodic):
            L = self.hi[ax] - self.lo[ax]
            x[:, ax] = self.lo[ax] + np.mod(x[:, ax] - self.lo[ax], L)
        return x

    def exit_fraction(self, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """Fraction ``s`` in ``[0, 1]`` of the segment ``x0 → x1`` inside the closed axes.

        ``1`` where the segment stays inside (up to a round-off tolerance).
        """
        s = np.ones(x0.shape[0])
        for ax in np.flatnonzero(~self.periodic):
            lo, hi = self.lo[ax], self.hi[ax]
            tol = 1e-12 * max(hi - lo, 1.0)
            below = x1[:, ax] < lo - tol
            above = x1[:, ax] > hi + tol
            viol = below | above
            if not viol.any():
                continue
            bound = np.where(below, lo, hi)
            d = x1[:, ax] - x0[:, ax]
            with np.errstate(divide="ignore", invalid="ignore"):
                f = np.where(viol & (d != 0.0), (bound - x0[:, ax]) / d, 0.0)
            s = np.where(viol, np.minimum(s, np.clip(f, 0.0, 1.0)), s)
        return s

    def clamp(self, x: np.ndarray) -> np.ndarray:
        """Clip points into the box along the closed axes (in place; returned)."""
        for ax in np.flatnonzero(~self.periodic):
            np.clip(x[:, ax], self.lo[ax], self.hi[ax], out=x[:, ax])
        return x


@dataclass
class PathResult:
    """Outcome of :func:`trace`.

    Attributes
    ----------
    x:
        End points ``(n, gdim)`` (exit points for paths that left the box).
    travelled:
        Time (``>= 0``) each point travelled before it stopped.
    exited:
        ``(n,)`` bool: left through a closed side.
    q_integral:
        ``∫ q(x(s), t_q) ds`` over the travelled part (``0`` without ``q``).
    """

    x: np.ndarray
    travelled: np.ndarray
    exited: np.ndarray
    q_integral: np.ndarray


def trace(
    x0: np.ndarray,
    t0: float,
    dt: float,
    nsub: int,
    velocity: Callable[[np.ndarray, float], np.ndarray],
    box: Box,
    q: Callable[[np.ndarray, float], np.ndarray] | None = None,
) -> PathResult:
    """Integrate ``dx/dt = V(x, t)`` from ``t0`` over ``dt`` (``< 0``: backwards).

    ``nsub`` midpoint (RK2) sub-steps; periodic axes wrap; a path that
    crosses a closed side stops at the crossing. Along the path the
    trapezoidal rule integrates ``q`` (a function of position only: the
    caller freezes its time, eq. 2.9 of the paper).

    Parameters
    ----------
    x0:
        Start points ``(n, gdim)``.
    t0, dt:
        Start time and (signed) time span.
    nsub:
        Number of sub-steps (``>= 1``).
    velocity:
        ``V(x, t) -> (n, gdim)``.
    box:
        Periodic / closed box.
    q:
        Optional integrand ``q(x, t) -> (n,)`` (``t`` a float).
    """
    x = box.wrap(np.array(x0, dtype=float, copy=True))
    n = x.shape[0]
    h = dt / nsub
    active = np.ones(n, dtype=bool)
    exited = np.zeros(n, dtype=bool)
    travelled = np.zeros(n)
    qi = np.zeros(n)
    q0 = q(x, t0) if q is not None else None
    for k in range(nsub):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        tk = t0 + k * h
        xa = x[idx]
        v1 = velocity(xa, tk)
        xm = box.wrap(xa + 0.5 * h * v1)
        v2 = velocity(xm, tk + 0.5 * h)
        xn = xa + h * v2
        s = box.exit_fraction(xa, xn)
        left = s < 1.0
        xn = np.where(left[:, None], xa + s[:, None] * (xn - xa), xn)
        box.clamp(box.wrap(xn))
        if q is not None:
            qn = q(xn, tk + h)
            qi[idx] += 0.5 * abs(h) * s * (q0[idx] + qn)
            q0[idx] = qn
        travelled[idx] += abs(h) * s
        x[idx] = xn
        if left.any():
            exited[idx[left]] = True
            active[idx[left]] = False
    return PathResult(x, travelled, exited, qi)
