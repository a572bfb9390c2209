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

from typing import Any, NamedTuple

import numpy as np

from pfem2x import compat
from pfem2x.particles import _kernels as K
from pfem2x.particles.cloud import Cloud
from pfem2x.particles.locate import MAXIT, LocateStats, resolve
from pfem2x.particles.pmesh import ParticleMesh

__all__ = ["advect", "nodal_values"]

VelocityLike = Any  # dolfinx Function | ndarray (ndofs, gdim) | callable v(x, t) -> (n, gdim)
SourceLike = Any  # dolfinx Function | ndarray (ndofs,) or (ndofs, k) | callable q(x, t) -> (n,)

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
    velocity_end: VelocityLike | None = None,
    source_end: SourceLike | None = None,
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
        (frozen at ``t``) or a callable ``q(x, t) -> (n,)``; a vector P1
        Function / nodal array ``(ndofs, k)`` is integrated per component
        into a field ``source_field`` of shape ``(k,)``.
    sort:
        Sort the particles by cell first (faster kernel).
    velocity_end, source_end:
        P1, ``theta = 0``: the values at ``t + dt``, the fields linear in time between.

    Returns
    -------
    LocateStats
        Sub-steps taken, particles deleted at outflow, migrated, fallbacks.
    """
    if sort:
        cloud.sort_by_cell()
    pm = cloud.pmesh
    inp = _inputs(pm, velocity, velocity_next, theta, courant, substeps, source, source_field)
    inp = _blend_inputs(pm, inp, velocity_end, source_end, theta)
    _check_source_field(cloud, source, source_field, inp.q.shape[1])
    _add_work_fields(cloud, dt, inp.q.shape[1])
    params = _params(inp, dt, theta, courant, gradient_courant)
    tables = _move_tables(cloud, inp, params)
    stats = LocateStats()
    try:
        more = True
        while more:
            status = _move_round(cloud, inp, params, tables, t, stats)
            more, _ = resolve(cloud, status, stats)
        if source is not None:
            _accumulate(cloud, source_field, source_scale)
    finally:
        for name in _WORK:
            cloud.remove_field(name)
    cloud.invalidate_order()
    return stats


def _move_tables(cloud: Cloud, inp: _Inputs, params: K.MoveParams) -> tuple | None:
    """The fields' per-cell tables of the compiled move, made once for all its rounds
    (:func:`~pfem2x.particles._kernels.move_tables`); ``None`` when the move has no
    compiled pass (callables without ``theta``)."""
    if (inp.vel_call or inp.src_call) and not params.theta > 0.0:
        return None
    return K.move_tables(inp.un, inp.du, inp.q, inp.dq, params, cloud.pmesh.arrays)


def _params(inp: _Inputs, dt: float, theta: float, courant: float, gcourant: float) -> K.MoveParams:
    """The kernel's parameters of one move."""
    f = float
    return K.MoveParams(f(dt), f(theta), f(courant), f(gcourant), inp.nsub, inp.has_q, inp.blend)


def _accumulate(cloud: Cloud, source_field: str, scale: float) -> None:
    """``source_field += scale * _acc`` (the path integral), the field made if new."""
    if source_field not in cloud:
        cloud.add_field(source_field, cloud.field_shape("_acc"))
    acc = cloud.field("_acc")
    cloud.field(source_field)[:] += acc if scale == 1.0 else scale * acc


def _check_source_field(
    cloud: Cloud, source: SourceLike | None, source_field: str | None, kq: int
) -> None:
    """An existing ``source_field`` must have the source's number of components."""
    if source is not None and source_field in cloud:
        if cloud.field_shape(source_field) != (() if kq == 1 else (kq,)):
            raise ValueError(
                f"source_field {source_field!r} has shape {cloud.field_shape(source_field)}, "
                f"the source {kq} component(s)"
            )


class _Inputs(NamedTuple):
    """The velocity and source of one :func:`advect` call, checked, with their P1 nodal values.

    ``un`` / ``q`` are placeholders (zeros) when the velocity / source is a
    callable (``vel_call`` / ``src_call``); ``q`` is ``(ndofs, k)`` (``k = 1``: a
    scalar source); ``un1`` is one only without ``theta``. With ``blend`` the
    velocity and the source change by ``du`` / ``dq`` over the step (else
    placeholders).
    """

    velocity: Any
    un: np.ndarray
    un1: np.ndarray
    vel_call: bool
    source: Any
    q: np.ndarray
    src_call: bool
    has_q: bool
    nsub: int
    du: np.ndarray = np.zeros((1, 1))
    dq: np.ndarray = np.zeros((1, 1))
    blend: bool = False


def _inputs(
    pm: ParticleMesh,
    velocity: VelocityLike,
    velocity_next: VelocityLike | None,
    theta: float,
    courant: float,
    substeps: int | None,
    source: SourceLike | None,
    source_field: str | None,
) -> _Inputs:
    """Check the arguments of :func:`advect` and take the nodal values of its P1 fields."""
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
    q = nodal_values(pm, source) if has_q else np.zeros((1, 1))
    if source is not None and source_field is None:
        raise ValueError("source needs source_field")
    return _Inputs(velocity, un, un1, vel_call, source, q, src_call, has_q, nsub)


def _blend_inputs(
    pm: ParticleMesh,
    inp: _Inputs,
    velocity_end: VelocityLike | None,
    source_end: SourceLike | None,
    theta: float,
) -> _Inputs:
    """``inp`` with the changes over the step of the velocity and the source (``blend``).

    ``inp`` itself without ``velocity_end`` and ``source_end``.
    """
    if velocity_end is None and source_end is None:
        return inp
    if inp.vel_call or inp.src_call or theta > 0.0:
        raise ValueError("velocity_end / source_end need P1 velocity and source and theta = 0")
    un = inp.un
    du = np.zeros_like(un) if velocity_end is None else nodal_values(pm, velocity_end, pm.gdim) - un
    if source_end is None:
        dq = np.zeros_like(inp.q)
    elif not inp.has_q:
        raise ValueError("source_end needs source")
    else:
        dq = nodal_values(pm, source_end, inp.q.shape[1]) - inp.q
    return inp._replace(du=np.ascontiguousarray(du), dq=np.ascontiguousarray(dq), blend=True)


def _add_work_fields(cloud: Cloud, dt: float, k: int = 1) -> None:
    """The per-particle move state: time left, source integral (``k`` components), aux, stage."""
    for name, shape, value in (
        ("_tl", (), dt),
        ("_acc", () if k == 1 else (k,), 0.0),
        ("_aux", (cloud.pmesh.gdim,), 0.0),
        ("_stage", (), K.STAGE_PATH),
    ):
        if name in cloud:
            cloud.field2d(name)[:] = value
        else:
            cloud.add_field(name, shape, value)


def _p1_pass(
    cloud: Cloud,
    inp: _Inputs,
    params: K.MoveParams,
    tables: tuple,
    general: bool,
    status: np.ndarray,
    stats: LocateStats,
) -> None:
    """The fused P1 kernel: every sub-step, or only the X-IVAS stage after the general path.

    ``tables``: the fields' per-cell tables (:func:`~pfem2x.particles._kernels.move_tables`).
    With ``general``, particles still on their path (stage 0) belong to the
    general path and are parked. Updates ``status`` of particles not stopped yet.
    """
    stage = cloud.field("_stage")
    parked = np.flatnonzero(stage == K.STAGE_PATH) if general else np.zeros(0, int)
    stage[parked] = K.STAGE_DONE  # the general path owns stage-0 particles
    # without the general path every particle is still moving (ST_OK): the kernel's own
    st2 = np.zeros(len(status), dtype=np.int8) if general else status
    state = K.MoveState(
        cloud.x,
        cloud.cells,
        cloud.field("_tl"),
        cloud.field2d("_aux"),
        cloud.field2d("_acc"),
        stage,
        st2,
    )
    pm = cloud.pmesh
    stats.substeps += K.advect_p1_tables(state, inp.un, inp.un1, inp.du, tables, params, pm.arrays)
    stage[parked] = K.STAGE_PATH
    if general:
        busy = status == K.ST_OK
        status[busy] = st2[busy]


def _move_round(
    cloud: Cloud,
    inp: _Inputs,
    params: K.MoveParams,
    tables: tuple | None,
    t0: float,
    stats: LocateStats,
) -> np.ndarray:
    """Move the particles of this rank as far as they go here; their status codes ``(n,)``.

    Particles stopped in the ghost layer (``ST_GHOST``) or at a boundary go to
    :func:`resolve`; those with time left continue in the next round. ``tables``: the
    compiled pass's (:func:`_move_tables`; ``None``: the move has none).
    """
    status = np.zeros(cloud.n, dtype=np.int8)
    general = inp.vel_call or inp.src_call
    if general:
        p = params
        _general_path(cloud, inp, t0, p.dt, p.courant, p.gcourant, p.theta, status, stats)
    if tables is not None:
        _p1_pass(cloud, inp, params, tables, general, status, stats)
    else:
        ghost = (status == K.ST_OK) & (cloud.cells >= cloud.pmesh.n_owned)
        status[ghost] = K.ST_GHOST
    return status


def _eval_velocity(
    pm: ParticleMesh, inp: _Inputs, x: np.ndarray, cells: np.ndarray, t: Any
) -> np.ndarray:
    """The velocity ``(n, gdim)`` at points ``x`` in ``cells`` at time(s) ``t``."""
    if inp.vel_call:
        return np.asarray(inp.velocity(x, t), dtype=np.float64).reshape(len(x), pm.gdim)
    return K.evaluate_p1(x, cells, inp.un, pm.arrays)


def _eval_source(
    pm: ParticleMesh, inp: _Inputs, x: np.ndarray, cells: np.ndarray, t: Any
) -> np.ndarray:
    """The source ``(n, k)`` at points ``x`` in ``cells`` at time(s) ``t``."""
    if inp.src_call:
        return np.asarray(inp.source(x, t), dtype=np.float64).reshape(len(x), 1)
    return K.evaluate_p1(x, cells, inp.q, pm.arrays)


def _general_path(
    cloud: Cloud,
    inp: _Inputs,
    t0: float,
    dt: float,
    courant: float,
    gcourant: float,
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
        v1 = _eval_velocity(pm, inp, x, c, tn)
        if inp.nsub > 0:
            m = np.maximum(np.ceil(tl / (dt / inp.nsub) - 1e-9), 1.0)
        else:
            rate = _step_rate(pm, inp, idx, x, c, tl, tn, v1, rate_g, courant, gcourant)
            m = np.maximum(np.ceil(tl * rate), 1.0)
        h = tl / m
        xm, cm = _predictor(pm, inp, x, c, h, v1)
        v2 = _eval_velocity(pm, inp, xm, cm, tn + h)
        if inp.vel_call:
            v2 = np.where(np.isfinite(v2), v2, v1)
        xn = x + 0.5 * h[:, None] * (v1 + v2)
        step = np.linalg.norm(xm - x, axis=1)
        rate_g[idx] = np.linalg.norm(v2 - v1, axis=1) / np.maximum(step, 1e-300)
        ends = _source_ends(pm, inp, x, xn, c, tn, h)  # before the walk moves xn (walls)
        cn, st, shifts = K.locate_many(xn, c, pm.arrays, MAXIT)
        if ends is not None:
            cloud.field2d("_acc")[idx] += _source_step(pm, inp, ends, xn, c, cn, st, tn, h)
        cloud.field2d("_aux")[idx] += xn - shifts - x
        cloud.x[idx] = xn
        cloud.cells[idx] = cn
        tl = np.where(tl - h > 1e-14 * dt, tl - h, 0.0)
        tl_all[idx] = tl
        stats.substeps += len(idx)
        stop = st != K.ST_OK
        status[idx[stop]] = st[stop]
        idx = idx[~stop & (tl > 0.0)]
    _end_path(cloud, status, dt, theta)


def _step_rate(
    pm: ParticleMesh,
    inp: _Inputs,
    idx: np.ndarray,
    x: np.ndarray,
    c: np.ndarray,
    tl: np.ndarray,
    tn: np.ndarray,
    v1: np.ndarray,
    rate_g: np.ndarray,
    courant: float,
    gcourant: float,
) -> np.ndarray:
    """Sub-steps per unit time of particles ``idx``: the Courant and velocity-gradient limits.

    A callable velocity has no cell gradient: its directional gradient is
    ``rate_g`` of the last sub-step, probed along ``v1`` on a first sub-step
    (``rate_g`` updated in place).
    """
    sp = np.linalg.norm(v1, axis=1)
    rate = sp / (courant * pm.h[c])
    if gcourant > 0.0 and inp.vel_call:
        new = rate_g[idx] == 0.0  # first sub-step: probe the gradient along v1
        if new.any():
            hp = (1.0 / np.maximum(rate[new], 1.0 / tl[new]))[:, None]
            vp = _eval_velocity(pm, inp, x[new] + hp * v1[new], c, tn[new])
            dv = np.linalg.norm(vp - v1[new], axis=1)
            rate_g[idx[new]] = dv / np.maximum(np.linalg.norm(hp * v1[new], axis=1), 1e-300)
        rate = np.maximum(rate, rate_g[idx] / gcourant)
    elif gcourant > 0.0:
        g = K.grad_norms(inp.un, c, pm.arrays)
        rate = np.maximum(rate, g / gcourant)
    return rate


def _predictor(
    pm: ParticleMesh,
    inp: _Inputs,
    x: np.ndarray,
    c: np.ndarray,
    h: np.ndarray,
    v1: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The Euler predictor of a Heun sub-step and its cell.

    A P1 velocity is evaluated in the predictor's cell: a predictor that
    leaves the mesh (not in a cell nor the ghost layer) falls back to ``x``.
    """
    xm = x + h[:, None] * v1
    if inp.vel_call:
        return xm, c
    cm, stm, _ = K.locate_many(xm, c, pm.arrays, MAXIT)
    bad = (stm != K.ST_OK) & (stm != K.ST_GHOST)
    cm = np.where(bad, c, cm)
    xm = np.where(bad[:, None], x, xm)
    return xm, cm


def _source_ends(
    pm: ParticleMesh,
    inp: _Inputs,
    x: np.ndarray,
    xn: np.ndarray,
    c: np.ndarray,
    tn: np.ndarray,
    h: np.ndarray,
) -> tuple[np.ndarray, np.ndarray | None] | None:
    """The source at both ends of a sub-step ``x -> xn``, taken before ``xn`` is walked.

    ``None`` without a source. The end value of a P1 source is left out
    (``None``): it needs the cell the walk finds, see :func:`_source_step`.
    """
    if inp.source is None:
        return None
    q0 = _eval_source(pm, inp, x, c, tn)
    q1 = _eval_source(pm, inp, xn, c, tn + h) if inp.src_call else None
    return q0, q1


def _source_step(
    pm: ParticleMesh,
    inp: _Inputs,
    ends: tuple[np.ndarray, np.ndarray | None],
    xn: np.ndarray,
    c: np.ndarray,
    cn: np.ndarray,
    st: np.ndarray,
    tn: np.ndarray,
    h: np.ndarray,
) -> np.ndarray:
    """The trapezoid integral of the source over one sub-step, after the walk of ``xn``.

    A P1 source at the end point ``xn`` (as the walk left it) is taken in its
    cell ``cn``; where the end point left the mesh (status ``st`` neither
    ``ST_OK`` nor ``ST_GHOST``) the start value stands in.
    """
    q0, q1 = ends
    if q1 is None:
        okw = (st == K.ST_OK) | (st == K.ST_GHOST)
        q1 = _eval_source(pm, inp, xn, np.where(okw, cn, c), tn + h)
        q1 = np.where(okw[:, None], q1, q0)
    return 0.5 * h[:, None] * (q0 + q1)


def _end_path(cloud: Cloud, status: np.ndarray, dt: float, theta: float) -> None:
    """Particles at the end of their path: to the X-IVAS stage (``theta > 0``) or done."""
    stage = cloud.field("_stage")
    tl_all = cloud.field("_tl")
    done = (stage == K.STAGE_PATH) & (tl_all <= 1e-14 * dt) & (status == K.ST_OK)
    if theta > 0.0:
        aux = cloud.field2d("_aux")
        aux[done] = cloud.x[done] - theta * aux[done]
        stage[done] = K.STAGE_THETA
    else:
        stage[done] = K.STAGE_DONE
    tl_all[done] = 0.0
