"""Numba kernels of the PFEM-2 frame's per-pass loads (:mod:`pfem2x.physics.flow.loads`).

They replace DOLFINx form assemblies, which they equal to round-off (the sums are taken in
another order); triangles run loops written out, other cells the generic loops.
"""

from __future__ import annotations

import numpy as np

from pfem2x.aot import njit

__all__ = ["force_load_kernel", "pressure_load_kernel"]


@njit(cache=True, error_model="numpy", inline="always")
def _cell_derivative(grads, c, k, dofs, f):  # pragma: no cover - compiled
    """``d f / d x_k`` of the P1 values ``f`` on cell ``c`` (its basis gradients ``grads[c]``)."""
    acc = 0.0
    for j in range(grads.shape[1]):
        acc += grads[c, j, k] * f[dofs[c, j]]
    return acc


@njit(cache=True, error_model="numpy")
def force_load_kernel(grads, vol, qdofs, vdofs, rho, g, q, s, out):  # pragma: no cover
    r"""``out[gdim * v + k] += |c| / (d + 1) * (rho_c (g_k - d_k q) + d_k s)`` per cell vertex.

    :math:`\int_c (\rho_c (g - \nabla q) + \nabla s)\cdot w` for the P1 vector test
    functions :math:`w` of the cells ``grads`` (``(n, d + 1, gdim)`` basis gradients),
    ``vol`` their volumes, ``qdofs`` / ``vdofs`` their P1 scalar / vector (block) dofs,
    ``rho`` their densities; ``q`` and ``s`` nodal P1 values (local, ghosts included).
    """
    n, nv, gd = grads.shape
    if gd == 2 and nv == 3:
        _force_load_tri(grads, vol, qdofs, vdofs, rho, g, q, s, out)
        return
    for c in range(n):
        w = vol[c] / nv
        for k in range(gd):
            dq = _cell_derivative(grads, c, k, qdofs, q)
            ds = _cell_derivative(grads, c, k, qdofs, s)
            val = w * (rho[c] * (g[k] - dq) + ds)
            for i in range(nv):
                out[gd * vdofs[c, i] + k] += val


@njit(cache=True, error_model="numpy")
def pressure_load_kernel(grads, vol, qdofs, vdofs, rho, g, q, Pi, u, out):  # pragma: no cover
    r"""``out[r] += int_c (grad u : grad u^T) r + (g - grad q + grad Pi / rho_c) . grad r``.

    The consistent pressure's right-hand side with the balanced force
    :math:`\rho_c(g - \nabla q) + \nabla\Pi` over :math:`\rho_c`, for the P1
    test functions :math:`r` of the cells (arguments as :func:`force_load_kernel`;
    ``u`` the P1 velocity's local values, ``gdim`` per node).
    """
    n, nv, gd = grads.shape
    if gd == 2 and nv == 3:
        _pressure_load_tri(grads, vol, qdofs, vdofs, rho, g, q, Pi, u, out)
        return
    G = np.empty((gd, gd))
    f = np.empty(gd)
    for c in range(n):
        for a in range(gd):
            dq = _cell_derivative(grads, c, a, qdofs, q)
            dpi = _cell_derivative(grads, c, a, qdofs, Pi)
            f[a] = g[a] - dq + dpi / rho[c]
            for b in range(gd):
                acc = 0.0
                for j in range(nv):
                    acc += u[gd * vdofs[c, j] + a] * grads[c, j, b]
                G[a, b] = acc
        ss = 0.0
        for a in range(gd):
            for b in range(gd):
                ss += G[a, b] * G[b, a]
        m = vol[c] / nv * ss
        for i in range(nv):
            fr = 0.0
            for a in range(gd):
                fr += f[a] * grads[c, i, a]
            out[qdofs[c, i]] += m + vol[c] * fr


@njit(cache=True, error_model="numpy")
def _force_load_tri(grads, vol, qdofs, vdofs, rho, g, q, s, out):  # pragma: no cover
    """:func:`force_load_kernel` on triangles, unrolled (the loops' bounds known)."""
    for c in range(grads.shape[0]):
        a0, a1, a2 = qdofs[c, 0], qdofs[c, 1], qdofs[c, 2]
        b0, b1, b2 = 2 * vdofs[c, 0], 2 * vdofs[c, 1], 2 * vdofs[c, 2]
        q0, q1, q2 = q[a0], q[a1], q[a2]
        s0, s1, s2 = s[a0], s[a1], s[a2]
        w = vol[c] / 3.0
        r = rho[c]
        for k in range(2):
            g0, g1, g2 = grads[c, 0, k], grads[c, 1, k], grads[c, 2, k]
            val = w * (r * (g[k] - (g0 * q0 + g1 * q1 + g2 * q2)) + (g0 * s0 + g1 * s1 + g2 * s2))
            out[b0 + k] += val
            out[b1 + k] += val
            out[b2 + k] += val


@njit(cache=True, error_model="numpy")
def _pressure_load_tri(grads, vol, qdofs, vdofs, rho, g, q, Pi, u, out):  # pragma: no cover
    """:func:`pressure_load_kernel` on triangles, unrolled."""
    for c in range(grads.shape[0]):
        a0, a1, a2 = qdofs[c, 0], qdofs[c, 1], qdofs[c, 2]
        b0, b1, b2 = 2 * vdofs[c, 0], 2 * vdofs[c, 1], 2 * vdofs[c, 2]
        x0, x1, x2 = grads[c, 0, 0], grads[c, 1, 0], grads[c, 2, 0]
        y0, y1, y2 = grads[c, 0, 1], grads[c, 1, 1], grads[c, 2, 1]
        q0, q1, q2 = q[a0], q[a1], q[a2]
        p0, p1, p2 = Pi[a0], Pi[a1], Pi[a2]
        r = rho[c]
        fx = g[0] - (x0 * q0 + x1 * q1 + x2 * q2) + (x0 * p0 + x1 * p1 + x2 * p2) / r
        fy = g[1] - (y0 * q0 + y1 * q1 + y2 * q2) + (y0 * p0 + y1 * p1 + y2 * p2) / r
        ux0, ux1, ux2 = u[b0], u[b1], u[b2]
        uy0, uy1, uy2 = u[b0 + 1], u[b1 + 1], u[b2 + 1]
        gxx = ux0 * x0 + ux1 * x1 + ux2 * x2
        gxy = ux0 * y0 + ux1 * y1 + ux2 * y2
        gyx = uy0 * x0 + uy1 * x1 + uy2 * x2
        gyy = uy0 * y0 + uy1 * y1 + uy2 * y2
        v = vol[c]
        m = v / 3.0 * (gxx * gxx + gxy * gyx + gyx * gxy + gyy * gyy)
        out[a0] += m + v * (fx * x0 + fy * y0)
        out[a1] += m + v * (fx * x1 + fy * y1)
        out[a2] += m + v * (fx * x2 + fy * y2)
