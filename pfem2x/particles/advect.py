"""Moving particles: X-IVAS streamline integration (eq. 2.10) with RK2 sub-steps.

Fast path (velocity and optional source given as P1 nodal values): one
fused Numba kernel per particle does all sub-steps, the barycentric walks,
wall/periodic handling and the source integral. General path (a velocity
or source given as a vectorised callable ``f(x, t)``): the same Heun
sub-steps vectorised over particles, one compiled walk per sub-step.
Both continue across ranks: particles stopped at the ghost layer are
migrated with their remaining time and finish their move on the owner.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x.particles import _kernels as K
from pfem2x.particles.cloud import Cloud
from pfem2x.particles.locate import MAXIT, LocateStats, resolve
from pfem2x.particles.pmesh import ParticleMesh

__all__ = ["advect", "nodal_values"]

VelocityLike = Any  # dolfinx Function | ndarray (ndofs, gdim) | callable v(x, t) -> (n, gdim)
SourceLike = Any  # dolfinx Function | ndarray (ndofs,) | callable q(x, t) -> (n,)

_WORK = ("_tl", "_acc", "_aux", "_stage")


def nodal_values(pm: ParticleMesh, f: Any, ncomp: int | None = None) -> np.ndarray:
    """P1 nodal values ``(ndofs_local + ghosts, k)`` of a Function or array.

    Arrays must be numbered like P1 dofs on this mesh (``pm.dofs``), with
    ghost entries up to date (the caller scatters forward).
    """
    if hasattr(f, "x") and hasattr(f, "function_space"):
        V = f.function_space
        dm = compat.dofmap_array(V)[: pm.n_cells]
        if dm.shape != pm.dofs.shape or not np.array_equal(dm, pm.dofs):
            raise ValueError("P1 function does not share the P1 dof numbering of the particle mesh")
        bs = int(V.dofmap.index_map_bs)
        a = np.asarray(f.x.array).reshape(-1, bs)
    else:
        a = np.asarray(f, dtype=np.float64)
        if a.ndim == 1:
            a = a.reshape(-1, 1)
    if a.shape[0] < pm.n_dofs:
        raise ValueError(f"nodal array has {a.shape[0]} rows, the mesh has {pm.n_dofs} P1 dofs")
    if ncomp is not None and a.shape[1] != ncomp:
        raise ValueError(f"nodal array has {a.shape[1]} components, expected {ncomp}")
    return np.ascontiguousarray(a, dtype=np.float64)


def advect(
    cloud: Cloud,
    velocity: VelocityLike,
    dt: float,
    t: float = 0.0,
    velocity_next: VelocityLike | None = None,
    theta: float = 0.0,
    courant: float = 0.5,
    gradient_courant: float = 0.1,
    substeps: int | None = None,
    source: SourceLike | None = None,
    source_field: str | None = None,
    source_scale: float = 1.0,
    sort: bool = True,
) -> LocateStats:
    """Move every particle over one time step ``dt`` (collective).

    Parameters
    ----------
    cloud:
        The particles (all in owned cells on entry and on exit).
    velocity:
        ``V^n``: a vector P1 Function, nodal array ``(ndofs, gdim)`` (P1 dof
        numbering, ghosts up to date), or a vectorised callable
        ``v(x, t) -> (n, gdim)`` (then ``theta`` must be 0).
    dt, t:
        Step size and start time.
    velocity_next, theta:
        ``V^{n+1}`` (P1) and the X-IVAS blend of eq. (2.10):
        ``x^{n+1} = x^n + (1-theta) int V^n(x(t)) dt + theta dt V^{n+1}(x^{n+1})``,
        the implicit part solved by Newton iterations (cell gradient of ``V^{n+1}``).
    courant:
        Local Courant number of one sub-step, ``|v| h_sub / h_cell``; the
        sub-step count of each particle adapts to its own speed and cell.
    gradient_courant:
        P1 velocities only: also ``h_sub * |grad V|_cell <= gradient_courant``
        (limits the turning per sub-step; 0 disables).
    substeps:
        Fixed number of equal sub-steps instead (overrides ``courant``).
    source, source_field, source_scale:
        Explicit source of eq. (2.9): ``source_field += source_scale *
        int_{t}^{t+dt} q(x_p(s), s) ds`` along the path (trapezoid per
        Heun sub-step). ``q`` is a P1 Function / nodal array ``(ndofs,)``
        (frozen at ``t``) or a callable ``q(x, t) -> (n,)``.
    sort:
        Sort the particles by cell first (faster kernel; cheap).

    Returns
    -------
    LocateStats
        Sub-steps taken, particles deleted at outflow, migrated, fallbacks.
    """
    pm = cloud.pmesh
    if sort:
        cloud.sort_by_cell()
    gd = pm.gdim
    nsub = int(substeps) if substeps else 0
    vel_call = callable(velocity) and not hasattr(velocity, "x")
    src_call = source is not None and callable(source) and not hasattr(source, "x")
    if vel_call and theta > 0.0:
        raise ValueError("theta > 0 needs P1 velocities (u^n and u^{n+1}), not a callable")
    if theta > 0.0 and velocity_next is None:
        raise ValueError("theta > 0 needs velocity_next")
    if not nsub and not courant > 0.0:
        raise ValueError("courant must be positive (or give substeps)")
    un = np.zeros((pm.n_dofs, gd)) if vel_call else nodal_values(pm, velocity, gd)
    un1 = nodal_values(pm, velocity_next, gd) if theta > 0.0 else np.zeros((1, gd))
    has_q = source is not None and not src_call
    q = nodal_values(pm, source, 1)[:, 0].copy() if has_q else np.zeros(1)
    if source is not None and source_field is None:
        raise ValueError("source needs source_field")

    cloud.add_field("_tl", (), dt)
    cloud.add_field("_acc")
    cloud.add_field("_aux", (gd,))
    cloud.add_field("_stage")
    cloud.field("_tl")[:] = dt
    cloud.field("_acc")[:] = 0.0
    cloud.field2d("_aux")[:] = 0.0
    cloud.field("_stage")[:] = K.STAGE_PATH
    params = K.MoveParams(
        float(dt), float(theta), float(courant), float(gradient_courant), nsub, bool(has_q)
    )
    stats = LocateStats()
    try:
        while True:
            n = cloud.n
            status = np.zeros(n, dtype=np.int8)
            general = vel_call or src_call
            if general:
                _general_path(
                    cloud, velocity, un, vel_call, source, src_call, q, t, dt, courant,
                    gradient_courant, nsub, theta, status, stats,
                )  # fmt: skip
            if not general or theta > 0.0:
                stage = cloud.field("_stage")
                parked = np.flatnonzero(stage == K.STAGE_PATH) if general else np.zeros(0, int)
                stage[parked] = K.STAGE_DONE  # the general path owns stage-0 particles
                st2 = np.zeros(n, dtype=np.int8)
                state = K.MoveState(
                    cloud.x,
                    cloud.cells,
                    cloud.field("_tl"),
                    cloud.field2d("_aux"),
                    cloud.field("_acc"),
                    stage,
                    st2,
                )
                stats.substeps += K.advect_p1(state, un, un1, q, params, pm.arrays)
                stage[parked] = K.STAGE_PATH
                busy = status == K.ST_OK
                status[busy] = st2[busy]
            else:
                ghost = (status == K.ST_OK) & (cloud.cells >= pm.n_owned)
                status[ghost] = K.ST_GHOST
            more, _ = resolve(cloud, status, stats)
            if not more:
                break
        if source is not None:
            if source_field not in cloud:
                cloud.add_field(source_field)
            cloud.field(source_field)[:] += source_scale * cloud.field("_acc")
    finally:
        for name in _WORK:
            cloud.remove_field(name)
    cloud.invalidate_order()
    return stats


def _eval_velocity(pm, velocity, un, vel_call, x, cells, t):
    if vel_call:
        return np.asarray(velocity(x, t), dtype=np.float64).reshape(len(x), pm.gdim)
    return K.evaluate_p1(x, cells, un, pm.arrays)


def _eval_source(pm, source, src_call, q, x, cells, t):
    if src_call:
        return np.asarray(source(x, t), dtype=np.float64).reshape(len(x))
    return K.evaluate_p1(x, cells, q.reshape(-1, 1), pm.arrays)[:, 0]


def _general_path(
    cloud: Cloud,
    velocity: Callable | Any,
    un: np.ndarray,
    vel_call: bool,
    source: Any,
    src_call: bool,
    q: np.ndarray,
    t0: float,
    dt: float,
    courant: float,
    gcourant: float,
    nsub: int,
    theta: float,
    status: np.ndarray,
    stats: LocateStats,
) -> None:
    """Vectorised Heun sub-steps for particles in stage 0 (callables involved)."""
    pm = cloud.pmesh
    stage = cloud.field("_stage")
    tl_all = cloud.field("_tl")
    idx = np.flatnonzero((stage == K.STAGE_PATH) & (tl_all > 1e-14 * dt))
    rate_g = np.zeros(cloud.n)  # directional velocity-gradient estimate of the last sub-step
    while len(idx):
        x = cloud.x[idx]
        c = cloud.cells[idx]
        tl = tl_all[idx]
        tn = t0 + dt - tl
        v1 = _eval_velocity(pm, velocity, un, vel_call, x, c, tn)
        if nsub > 0:
            m = np.maximum(np.ceil(tl / (dt / nsub) - 1e-9), 1.0)
        else:
            sp = np.linalg.norm(v1, axis=1)
            rate = sp / (courant * pm.h[c])
            if gcourant > 0.0 and vel_call:
                new = rate_g[idx] == 0.0  # first sub-step: probe the gradient along v1
                if new.any():
                    hp = (1.0 / np.maximum(rate[new], 1.0 / tl[new]))[:, None]
                    vp = _eval_velocity(pm, velocity, un, True, x[new] + hp * v1[new], c, tn[new])
                    dv = np.linalg.norm(vp - v1[new], axis=1)
                    rate_g[idx[new]] = dv / np.maximum(np.linalg.norm(hp * v1[new], axis=1), 1e-300)
                rate = np.maximum(rate, rate_g[idx] / gcourant)
            elif gcourant > 0.0:
                g = K.grad_norms(un, c, pm.arrays)
                rate = np.maximum(rate, g / gcourant)
            m = np.maximum(np.ceil(tl * rate), 1.0)
        h = tl / m
        xm = x + h[:, None] * v1
        if vel_call:
            cm = c
        else:
            cm, stm, _ = K.locate_many(xm, c, pm.arrays, MAXIT)
            bad = (stm != K.ST_OK) & (stm != K.ST_GHOST)
            cm = np.where(bad, c, cm)
            xm = np.where(bad[:, None], x, xm)
        v2 = _eval_velocity(pm, velocity, un, vel_call, xm, cm, tn + h)
        if vel_call:
            v2 = np.where(np.isfinite(v2), v2, v1)
        xn = x + 0.5 * h[:, None] * (v1 + v2)
        step = np.linalg.norm(xm - x, axis=1)
        rate_g[idx] = np.linalg.norm(v2 - v1, axis=1) / np.maximum(step, 1e-300)
        if source is not None:
            q0 = _eval_source(pm, source, src_call, q, x, c, tn)
            q1 = _eval_source(pm, source, src_call, q, xn, c, tn + h) if src_call else None
        cn, st, shifts = K.locate_many(xn, c, pm.arrays, MAXIT)
        okw = (st == K.ST_OK) | (st == K.ST_GHOST)
        if source is not None:
            if not src_call:
                q1 = np.where(
                    okw,
                    _eval_source(pm, source, src_call, q, xn, np.where(okw, cn, c), tn + h),
                    q0,
                )
            cloud.field("_acc")[idx] += 0.5 * h * (q0 + q1)
        cloud.field2d("_aux")[idx] += xn - shifts - x
        cloud.x[idx] = xn
        cloud.cells[idx] = cn
        tl = np.where(tl - h > 1e-14 * dt, tl - h, 0.0)
        tl_all[idx] = tl
        stats.substeps += len(idx)
        stop = st != K.ST_OK
        status[idx[stop]] = st[stop]
        idx = idx[~stop & (tl > 0.0)]
    done = (stage == K.STAGE_PATH) & (tl_all <= 1e-14 * dt) & (status == K.ST_OK)
    if theta > 0.0:
        aux = cloud.field2d("_aux")
        aux[done] = cloud.x[done] - theta * aux[done]
        stage[done] = K.STAGE_THETA
    else:
        stage[done] = K.STAGE_DONE
    tl_all[done] = 0.0
