"""Interface curvature against an ellipse's exact curvature: the fit's and the smoothing's window.

A circle is fitted exactly by every variant of :mod:`pfem2x.physics.flow.curvature`; an
ellipse is not, and its curvature varies along the interface, so the bias of a fit window
and of the smoothing along the interface shows. The ellipse's exact signed distance is
sampled at the nodes of the cut cells (the level set's samples) or at scattered points
within 1.5 h of it, 16 per square of the mesh (PFEM-2's particles), on the structured
triangulation of the unit square (each square split in two). Per segment of the P1
iso-line, the relative error of its curvature against the exact one at the closest point
of the ellipse; the table gives the largest over the interface and the RMS.

    python benchmarks/curvature_ellipse.py > curvature_ellipse.md
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from pfem2x.physics.flow.curvature import (
    distance_curvature,
    oriented_segments,
    smooth_along,
    smooth_quadratic,
)

Field = Callable[[np.ndarray], np.ndarray]


def ellipse(a: float, b: float, centre: np.ndarray) -> tuple[Field, Field]:
    """Signed distance (> 0 inside) and the curvature at the closest point of an ellipse.

    The closest point's parameter by Newton's method from the polar angle (for points
    closer to the ellipse than its smallest radius of curvature).
    """

    def closest(p: np.ndarray) -> np.ndarray:
        x, y = (p - centre).T
        t = np.arctan2(a * y, b * x)
        for _ in range(30):
            st, ct = np.sin(t), np.cos(t)
            f = (a * a - b * b) * st * ct - x * a * st + y * b * ct
            df = (a * a - b * b) * (ct * ct - st * st) - x * a * ct - y * b * st
            t = t - f / df
        return t

    def sdist(p: np.ndarray) -> np.ndarray:
        t = closest(p)
        foot = centre + np.stack([a * np.cos(t), b * np.sin(t)], 1)
        inside = ((p[:, 0] - centre[0]) / a) ** 2 + ((p[:, 1] - centre[1]) / b) ** 2 < 1.0
        return np.where(inside, 1.0, -1.0) * np.linalg.norm(p - foot, axis=1)

    def kappa(p: np.ndarray) -> np.ndarray:
        t = closest(p)
        return a * b / (a * a * np.sin(t) ** 2 + b * b * np.cos(t) ** 2) ** 1.5

    return sdist, kappa


def grid(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The unit square's ``n`` × ``n`` squares, each split in two: coordinates and cells."""
    x = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(x, x, indexing="ij")
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    cells = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return np.stack([X.ravel(), Y.ravel()], 1), cells


def errors(a: float, b: float, n: int, seed: int = 3) -> dict[str, tuple[float, float]]:
    """Largest and RMS relative curvature error of each variant, ellipse ``a`` × ``b``, ``n``."""
    sdist, kappa = ellipse(a, b, np.array([0.5123, 0.4871]))  # off the mesh's symmetry
    xy, cells = grid(n)
    phi = sdist(xy)
    segs, cut, nrm = oriented_segments(phi[cells], xy[cells], normals=True)
    exact = kappa(segs.mean(axis=1))
    pts = np.random.default_rng(seed).random((16 * n * n, 2))
    d = sdist(pts)
    near = np.abs(d) < 1.5 / n
    pts, d = pts[near], d[near]
    nodes = np.unique(cells[cut])
    h = 1.0 / n
    k_nodes = distance_curvature(segs, nrm, xy[nodes], phi[nodes], 3.0 * h)[0]
    k3 = distance_curvature(segs, nrm, pts, d, 3.0 * h)[0]
    k2 = distance_curvature(segs, nrm, pts, d, 2.0 * h)[0]
    extrapolated = (9.0 * k2 - 4.0 * k3) / 5.0
    rows = {
        "nodes, fit 3 h, mean 3 h": smooth_along(segs, k_nodes, 3.0 * h),
        "nodes, fit 3 h, quadratic 4 h": smooth_quadratic(segs, k_nodes, 4.0 * h),
        "particles, fit 3 h, mean 3 h": smooth_along(segs, k3, 3.0 * h),
        "particles, fit 3 h, no smoothing": k3,
        "particles, fit 3 h, quadratic 4 h": smooth_quadratic(segs, k3, 4.0 * h),
        "particles, fits 2 h and 3 h extrapolated, no smoothing": extrapolated,
        "particles, fits 2 h and 3 h extrapolated, quadratic 4 h": smooth_quadratic(
            segs, extrapolated, 4.0 * h
        ),
    }
    out = {}
    for name, k in rows.items():
        e = k / exact - 1.0
        out[name] = (float(np.abs(e).max()), float(np.sqrt(np.mean(e * e))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[40, 80, 160], help="cells per side")
    args = ap.parse_args()
    shapes = ((0.3, 0.2), (0.37, 0.169))
    cols = [(s, n) for s in shapes for n in args.n]
    res = {(s, n): errors(*s, n) for s, n in cols}
    head = " | ".join(f"{a} × {b}, h = 1/{n}" for (a, b), n in cols)
    print(f"| samples, curvature | {head} |")
    print("|---|" + "---|" * len(cols))
    for name in res[cols[0]]:
        cells = " | ".join(f"{res[c][name][0]:.1e} / {res[c][name][1]:.1e}" for c in cols)
        print(f"| {name} | {cells} |")


if __name__ == "__main__":
    main()
