"""Case diagnostics of the paper's scalar test cases (``scene.case``).

- ``zalesak``: area of the disk ``{T >= 0.5}``, its change, the area of the
  symmetric difference with the exact shape and the L1 error of the field
  (sub-cell quadrature, so sharp fronts are measured inside cells).
- ``gaussian-hill``: the peak of the hill over time and a reference peak:
  in the rotating frame the problem is pure diffusion, so the exact peak is
  the initial hill convolved with the heat kernel, evaluated at its centre.
- ``manufactured-1d``: nothing beyond the exact-solution error that
  :class:`~pfem2x.physics.transport.TransportBase` always reports.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.compat import MPI
from pfem2x.scene import SceneError

__all__ = ["Case", "make_case", "subcell_points"]


def subcell_points(tdim: int, k: int) -> np.ndarray:
    """Barycentric coordinates ``(k**tdim, tdim+1)`` of an equal-weight sub-cell rule.

    The centroids of the ``k**tdim`` congruent sub-simplices of a uniform
    refinement (interval, triangle).
    """
    if tdim == 1:
        s = (np.arange(k) + 0.5) / k
        return np.stack([1.0 - s, s], axis=1)
    if tdim == 2:
        pts = []
        for i in range(k):
            for j in range(k - i):
                pts.append(((i + 1 / 3) / k, (j + 1 / 3) / k))
                if i + j <= k - 2:
                    pts.append(((i + 2 / 3) / k, (j + 2 / 3) / k))
        a = np.array(pts)
        return np.concatenate([1.0 - a.sum(axis=1, keepdims=True), a], axis=1)
    raise ValueError(f"sub-cell quadrature is implemented for tdim 1 and 2, got {tdim}")


class Case:
    """Case-specific diagnostics (base: none)."""

    name = ""

    def diagnostics(self, solver: Any, t: float) -> dict[str, float]:
        """Extra scalar diagnostics at time ``t`` (global values)."""
        return {}

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        """Extra summary metrics from the diagnostics history."""
        return {}


class ZalesakCase(Case):
    """Zalesak's slotted disk ``{T >= level}``; the exact shape comes from ``transport.exact``."""

    name = "zalesak"

    def __init__(self, solver: Any, level: float = 0.5, k: int = 4):
        if solver.problem.exact is None:
            raise SceneError("transport.exact: required by scene.case = 'zalesak'")
        t = solver.domain.table
        if t.tdim != 2:
            raise SceneError("scene.case: 'zalesak' needs a 2D mesh")
        n = t.num_cells_owned
        self.level = level
        self.lam = subcell_points(2, k)  # (s, 3)
        self.w = np.repeat(t.volume[:n] / len(self.lam), len(self.lam))
        # physical sample points (n*s, gdim)
        self.x = np.einsum("si,nid->nsd", self.lam, t.coords[:n]).reshape(-1, t.gdim)
        self.dofs = compat.dofmap_array(solver.V)[:n]
        self.exact = solver.problem.exact
        self.comm: MPI.Comm = solver.comm

    def diagnostics(self, solver: Any, t: float) -> dict[str, float]:
        T = solver.T.x.array
        th = np.einsum("si,ni->ns", self.lam, T[self.dofs]).ravel()
        te = self.exact(self.x, t)
        inside_h = th >= self.level
        inside_e = te >= self.level
        loc = np.array(
            [
                np.sum(self.w[inside_h]),
                np.sum(self.w[inside_e]),
                np.sum(self.w[inside_h != inside_e]),
                np.sum(self.w * np.abs(th - te)),
            ]
        )
        glob = np.zeros_like(loc)
        self.comm.Allreduce(loc, glob, op=MPI.SUM)
        return {
            "area": float(glob[0]),
            "area_exact": float(glob[1]),
            "sym_diff": float(glob[2]),
            "l1_error": float(glob[3]),
        }

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        h0, h1 = history[0], history[-1]
        return {
            "area_initial": h0["area"],
            "area_final": h1["area"],
            "area_rel_change": (h1["area"] - h0["area"]) / h0["area"] if h0["area"] else 0.0,
            "area_rel_error_final": (h1["area"] - h1["area_exact"]) / h1["area_exact"]
            if h1["area_exact"]
            else 0.0,
            "sym_diff_final": h1["sym_diff"],
            "sym_diff_rel_final": h1["sym_diff"] / h1["area_exact"] if h1["area_exact"] else 0.0,
            "l1_error_final": h1["l1_error"],
        }


class GaussianHillCase(Case):
    """Peak of the rotating, diffusing cosine hill and its exact value.

    Needs ``params`` ``x0, y0, sigma, kappa`` (paper eq. 5.5). The exact peak
    at time ``t`` is ``(T0 * G_t)(x0)``, with ``G_t`` the heat kernel of
    variance ``2 kappa t`` per direction (rigid rotation leaves it unchanged).
    """

    name = "gaussian-hill"

    def __init__(self, solver: Any, per_sigma: int = 100):
        p = solver.scene.params
        missing = [k for k in ("x0", "y0", "sigma", "kappa") if k not in p]
        if missing:
            raise SceneError(f"params.{missing[0]}: required by scene.case = 'gaussian-hill'")
        self.kappa = p["kappa"] if solver.problem.kappa is not None else 0.0
        x0, y0, s = p["x0"], p["y0"], p["sigma"]
        self.h = s / per_sigma
        r = 1.6 * s
        g = np.arange(-r, r + 0.5 * self.h, self.h)
        gx, gy = np.meshgrid(g, g, indexing="ij")
        pts = np.stack([x0 + gx.ravel(), y0 + gy.ravel()], axis=1)
        self.r2 = (gx**2 + gy**2).ravel()
        self.t0 = solver.problem.initial(pts, 0.0)
        self.peak0 = float(solver.problem.initial(np.array([[x0, y0]]), 0.0)[0])

    def reference_peak(self, t: float) -> float:
        """Exact peak at time ``t``."""
        var = 2.0 * self.kappa * t
        if var <= (0.25 * self.h) ** 2:
            return self.peak0
        g = np.exp(-self.r2 / (2.0 * var)) / (2.0 * np.pi * var)
        return float(np.sum(self.t0 * g) * self.h**2)

    def diagnostics(self, solver: Any, t: float) -> dict[str, float]:
        arr = solver.T.x.array
        peak = float(solver.comm.allreduce(arr.max() if len(arr) else -np.inf, op=MPI.MAX))
        return {"peak": peak, "peak_ref": self.reference_peak(t)}

    def metrics(self, history: list[dict[str, float]]) -> dict[str, Any]:
        rel = [(h["peak"] - h["peak_ref"]) / h["peak_ref"] for h in history]
        return {
            "peak_final": history[-1]["peak"],
            "peak_ref_final": history[-1]["peak_ref"],
            "peak_rel_error_final": float(rel[-1]),
            "peak_rel_error_max": float(np.max(np.abs(rel))),
        }


_CASES = {"zalesak": ZalesakCase, "gaussian-hill": GaussianHillCase}


def make_case(name: str, solver: Any) -> Case:
    """The case hook named by ``scene.case`` (a no-op :class:`Case` for other names)."""
    cls = _CASES.get(name)
    return cls(solver) if cls is not None else Case()
