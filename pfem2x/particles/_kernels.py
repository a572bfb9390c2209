"""Numba kernels of the particle layer (no DOLFINx, no MPI, no Python objects).

Every kernel works on plain arrays of the cached mesh arrays (see
:class:`pfem2x.particles.pmesh.ParticleMesh`) and loops over particles or
cells in compiled code. All of them are written for any dimension 1..3 and
work with Numba 0.56 (Debian) and 0.68 (PyPI).

Facet codes in ``nbr`` (cells, tdim+1): ``>= 0`` the neighbour cell (for a
periodic facet: the cell holding the image point), ``WALL = -1``,
``REMOTE = -2`` (beyond this rank's ghost layer, or a periodic image that is
not local), ``OUTFLOW = -3``. ``pshift`` (cells, tdim+1) is ``0`` or
``±(axis+1)``: crossing that facet shifts the point by ``∓period[axis]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

WALL = -1
REMOTE = -2
OUTFLOW = -3

# walk / particle status codes
ST_OK = 0  # located in an owned cell (or still moving)
ST_GHOST = 1  # located in a local ghost cell: hand to the cell's owner
ST_REMOTE = 2  # position known, cell not local: global search
ST_OUTFLOW = 3  # left through an outflow facet: delete
ST_FAIL = 4  # walk did not converge: bounding-box fallback

# advect stages
STAGE_PATH = 0
STAGE_THETA = 1
STAGE_DONE = 2

TOL = 1e-10  # barycentric tolerance for "inside"
EPS_IN = 1e-9  # barycentric offset used to push a point back inside a wall


@njit(cache=True)
def _bary(x, c, origin, inv, lam):
    """Barycentric coordinates of ``x`` in cell ``c`` into ``lam``; returns min."""
    tdim = inv.shape[1]
    gdim = inv.shape[2]
    s = 0.0
    for i in range(tdim):
        v = 0.0
        for j in range(gdim):
            v += inv[c, i, j] * (x[j] - origin[c, j])
        lam[i + 1] = v
        s += v
    lam[0] = 1.0 - s
    m = lam[0]
    for i in range(1, tdim + 1):
        if lam[i] < m:
            m = lam[i]
    return m


@njit(cache=True)
def _project_to_facet(x, c, i, lam_i, inv):
    """Move ``x`` onto the plane ``lambda_i = EPS_IN`` of cell ``c`` (drops the overshoot)."""
    tdim = inv.shape[1]
    gdim = inv.shape[2]
    g2 = 0.0
    gv = np.zeros(3)
    for j in range(gdim):
        if i == 0:
            v = 0.0
            for k in range(tdim):
                v -= inv[c, k, j]
        else:
            v = inv[c, i - 1, j]
        gv[j] = v
        g2 += v * v
    f = (lam_i - EPS_IN) / g2
    for j in range(gdim):
        x[j] -= f * gv[j]


@njit(cache=True)
def walk(x, c, origin, inv, nbr, pshift, period, lam, shift, maxit):
    """Walk from cell ``c`` to the cell containing ``x`` (modified in place).

    Walls project ``x`` back inside (slip), periodic facets wrap ``x`` (the
    applied translation is added to ``shift``). Returns ``(cell, status)``;
    on success ``lam`` holds the barycentric coordinates of ``x`` in ``cell``.
    """
    tdim = inv.shape[1]
    for _ in range(maxit):
        m = _bary(x, c, origin, inv, lam)
        if m >= -TOL:
            return c, ST_OK
        # leave through the most negative facet; a wall there pushes x back inside
        best = 0
        bv = lam[0]
        for i in range(1, tdim + 1):
            if lam[i] < bv:
                bv = lam[i]
                best = i
        wb = -1
        if nbr[c, best] == WALL:
            wb = best
            best = -1
        wv = bv
        if best >= 0:
            ps = pshift[c, best]
            if ps != 0:
                ax = abs(ps) - 1
                d = -period[ax] if ps > 0 else period[ax]
                x[ax] += d
                shift[ax] += d
            nb = nbr[c, best]
            if nb >= 0:
                c = nb
                continue
            if nb == OUTFLOW:
                return c, ST_OUTFLOW
            return c, ST_REMOTE
        _project_to_facet(x, c, wb, wv, inv)
    return c, ST_FAIL


@njit(cache=True)
def _eval_vec(vals, dofs, c, lam, out, scale, add):
    """``out (+)= scale * sum_i lam_i vals[dofs[c, i]]`` for a ``(ndofs, k)`` array."""
    k = vals.shape[1]
    nv = dofs.shape[1]
    for j in range(k):
        v = 0.0
        for i in range(nv):
            v += lam[i] * vals[dofs[c, i], j]
        if add:
            out[j] += scale * v
        else:
            out[j] = scale * v


@njit(cache=True)
def _eval_scalar(vals, dofs, c, lam):
    v = 0.0
    for i in range(dofs.shape[1]):
        v += lam[i] * vals[dofs[c, i]]
    return v


@njit(cache=True)
def _grad_norm(vals, dofs, c, inv):
    """Frobenius norm of the (cell-constant) gradient of a P1 vector field in cell ``c``."""
    tdim = inv.shape[1]
    gdim = inv.shape[2]
    k = vals.shape[1]
    s = 0.0
    for a in range(k):
        for b in range(gdim):
            g0 = 0.0
            for i in range(tdim):
                g0 -= inv[c, i, b]
            v = vals[dofs[c, 0], a] * g0
            for i in range(tdim):
                v += vals[dofs[c, i + 1], a] * inv[c, i, b]
            s += v * v
    return np.sqrt(s)


@njit(cache=True)
def grad_norms(vals, dofs, cells, inv):
    """:func:`_grad_norm` for many cells."""
    out = np.empty(cells.shape[0])
    for p in range(cells.shape[0]):
        out[p] = _grad_norm(vals, dofs, cells[p], inv)
    return out


@njit(cache=True)
def locate_many(x, cells, origin, inv, nbr, pshift, period, n_owned, maxit):
    """Walk every point ``x[p]`` from ``cells[p]``; returns ``(cells, status, shifts)``.

    ``x`` is modified in place (walls, periodic wrap). Status as in :func:`walk`,
    with ``ST_GHOST`` for points found in a ghost cell.
    """
    n = x.shape[0]
    gdim = x.shape[1]
    out = np.empty(n, dtype=np.int32)
    st = np.empty(n, dtype=np.int8)
    shifts = np.zeros((n, gdim))
    lam = np.empty(4)
    xp = np.empty(3)
    sh = np.zeros(3)
    for p in range(n):
        for j in range(gdim):
            xp[j] = x[p, j]
            sh[j] = 0.0
        c, s = walk(xp, cells[p], origin, inv, nbr, pshift, period, lam, sh, maxit)
        if s == ST_OK and c >= n_owned:
            s = ST_GHOST
        out[p] = c
        st[p] = s
        for j in range(gdim):
            x[p, j] = xp[j]
            shifts[p, j] = sh[j]
    return out, st, shifts


@njit(cache=True)
def contains(x, cells, origin, inv, tol):
    """Whether each ``x[p]`` lies in ``cells[p]`` (barycentric tolerance ``tol``)."""
    n = x.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    lam = np.empty(4)
    for p in range(n):
        c = cells[p]
        if c < 0:
            continue
        out[p] = _bary(x[p], c, origin, inv, lam) >= -tol
    return out


@njit(cache=True)
def clamp_into(x, cells, origin, inv, coords):
    """Move each ``x[p]`` to the closest point of ``cells[p]`` in barycentric terms."""
    n = x.shape[0]
    gdim = x.shape[1]
    lam = np.empty(4)
    for p in range(n):
        c = cells[p]
        _bary(x[p], c, origin, inv, lam)
        nv = inv.shape[1] + 1
        s = 0.0
        for i in range(nv):
            lam[i] = min(max(lam[i], EPS_IN), 1.0)
            s += lam[i]
        for j in range(gdim):
            v = 0.0
            for i in range(nv):
                v += lam[i] / s * coords[c, i, j]
            x[p, j] = v


@njit(cache=True)
def theta_stage(xp, c, y, theta, dt, un1, dofs, origin, inv, nbr, pshift, period, lam, sh, hc):
    """Fixed point of eq. (2.10): ``x = y + theta*dt*V^{n+1}(x)`` starting at ``xp`` in ``c``.

    ``y`` is shifted together with ``xp`` when the walk wraps. Returns
    ``(cell, status)``.
    """
    gdim = un1.shape[1]
    v = np.empty(3)
    xn = np.empty(3)
    for _ in range(30):
        _bary(xp, c, origin, inv, lam)
        _eval_vec(un1, dofs, c, lam, v, 1.0, False)
        d2 = 0.0
        for j in range(gdim):
            xn[j] = y[j] + theta * dt * v[j]
            d2 += (xn[j] - xp[j]) ** 2
        for j in range(gdim):
            sh[j] = 0.0
        c2, s = walk(xn, c, origin, inv, nbr, pshift, period, lam, sh, 1000)
        for j in range(gdim):
            xp[j] = xn[j]
            y[j] += sh[j]
        if s != ST_OK:
            return c2, s
        c = c2
        if d2 <= (1e-12 * hc[c]) ** 2:
            break
    return c, ST_OK


@njit(cache=True)
def advect_p1(
    x,
    cell,
    t_left,
    aux,
    acc,
    stage,
    status,
    dt,
    un,
    un1,
    theta,
    q,
    has_q,
    courant,
    gcourant,
    nsub,
    origin,
    inv,
    nbr,
    pshift,
    period,
    hc,
    dofs,
    n_owned,
):
    """Fused X-IVAS move + locate of every unfinished particle (P1 velocity).

    Heun (RK2) sub-steps along the streamline of ``un`` (``(ndofs, gdim)``),
    each of local Courant number ``courant`` and at most ``gcourant``
    times the inverse velocity-gradient norm of the cell (or ``dt/nsub``
    when ``nsub > 0``); then, when ``theta > 0``, the fixed point of eq. (2.10)
    with ``un1``. Along the path ``acc += int q dt`` (trapezoid per sub-step)
    when ``has_q``. ``aux`` holds the accumulated displacement (stage 0) or
    the anchor ``y`` (stage 1). Returns the number of sub-steps taken.
    """
    n = x.shape[0]
    gdim = x.shape[1]
    lam = np.empty(4)
    lam2 = np.empty(4)
    xp = np.empty(3)
    xm = np.empty(3)
    xn = np.empty(3)
    v1 = np.empty(3)
    v2 = np.empty(3)
    sh = np.zeros(3)
    y = np.empty(3)
    nsteps = 0
    for p in range(n):
        if stage[p] == STAGE_DONE:
            continue
        c = cell[p]
        for j in range(gdim):
            xp[j] = x[p, j]
        st = ST_OK
        tl = t_left[p]
        a = acc[p]
        if stage[p] == STAGE_PATH:
            while tl > 1e-14 * dt:
                _bary(xp, c, origin, inv, lam)
                _eval_vec(un, dofs, c, lam, v1, 1.0, False)
                if nsub > 0:
                    h = dt / nsub
                    m = np.ceil(tl / h - 1e-9)
                    if m < 1.0:
                        m = 1.0
                    h = tl / m
                else:
                    sp = 0.0
                    for j in range(gdim):
                        sp += v1[j] * v1[j]
                    sp = np.sqrt(sp)
                    rate = sp / (courant * hc[c])
                    if gcourant > 0.0:
                        gr = _grad_norm(un, dofs, c, inv) / gcourant
                        if gr > rate:
                            rate = gr
                    m = np.ceil(tl * rate)
                    if m < 1.0:
                        m = 1.0
                    h = tl / m
                # midpoint (predictor) with retries when it leaves the local mesh
                ok = False
                for _r in range(12):
                    for j in range(gdim):
                        xm[j] = xp[j] + h * v1[j]
                        sh[j] = 0.0
                    cm, s = walk(xm, c, origin, inv, nbr, pshift, period, lam2, sh, 1000)
                    if s == ST_OK:
                        ok = True
                        break
                    if s == ST_OUTFLOW or s == ST_FAIL:
                        break
                    if c >= n_owned:  # REMOTE from a ghost cell: let the owner continue
                        break
                    h *= 0.5
                if not ok:
                    if s == ST_REMOTE and c >= n_owned:
                        st = ST_GHOST
                        break
                    # outflow / fail / remote from an owned cell: explicit Euler step
                    for j in range(gdim):
                        xn[j] = xp[j] + h * v1[j]
                    q0 = _eval_scalar(q, dofs, c, lam) if has_q else 0.0
                    for j in range(gdim):
                        sh[j] = 0.0
                    cn, s = walk(xn, c, origin, inv, nbr, pshift, period, lam2, sh, 1000)
                    if has_q:
                        a += h * q0
                    for j in range(gdim):
                        aux[p, j] += xn[j] - sh[j] - xp[j]
                        xp[j] = xn[j]
                    tl -= h
                    nsteps += 1
                    c = cn
                    st = s if s != ST_OK else (ST_GHOST if c >= n_owned else ST_OK)
                    if st == ST_OK:
                        continue
                    break
                _eval_vec(un, dofs, cm, lam2, v2, 1.0, False)
                for j in range(gdim):
                    xn[j] = xp[j] + 0.5 * h * (v1[j] + v2[j])
                    sh[j] = 0.0
                q0 = _eval_scalar(q, dofs, c, lam) if has_q else 0.0
                cn, s = walk(xn, c, origin, inv, nbr, pshift, period, lam2, sh, 1000)
                if has_q and s == ST_OK:
                    a += 0.5 * h * (q0 + _eval_scalar(q, dofs, cn, lam2))
                elif has_q:
                    a += h * q0
                for j in range(gdim):
                    aux[p, j] += xn[j] - sh[j] - xp[j]
                    xp[j] = xn[j]
                tl -= h
                nsteps += 1
                c = cn
                if s != ST_OK:
                    st = s
                    break
            if st == ST_OK:
                tl = 0.0
                if theta > 0.0:
                    stage[p] = STAGE_THETA
                    for j in range(gdim):
                        aux[p, j] = xp[j] - theta * aux[p, j]
                else:
                    stage[p] = STAGE_DONE
        if st == ST_OK and stage[p] == STAGE_THETA:
            for j in range(gdim):
                y[j] = aux[p, j]
            c, st = theta_stage(
                xp, c, y, theta, dt, un1, dofs, origin, inv, nbr, pshift, period, lam, sh, hc
            )
            for j in range(gdim):
                aux[p, j] = y[j]
            if st == ST_OK:
                stage[p] = STAGE_DONE
        if st == ST_OK and c >= n_owned:
            st = ST_GHOST
        for j in range(gdim):
            x[p, j] = xp[j]
        cell[p] = c
        t_left[p] = tl
        acc[p] = a
        status[p] = st
    return nsteps


@njit(cache=True)
def evaluate_p1(x, cells, vals, origin, inv, dofs):
    """Values of a P1 field ``vals (ndofs, k)`` at the points ``x`` in ``cells``."""
    n = x.shape[0]
    k = vals.shape[1]
    out = np.empty((n, k))
    lam = np.empty(4)
    tmp = np.empty(k)
    for p in range(n):
        c = cells[p]
        _bary(x[p], c, origin, inv, lam)
        _eval_vec(vals, dofs, c, lam, tmp, 1.0, False)
        for j in range(k):
            out[p, j] = tmp[j]
    return out


@njit(cache=True)
def project_accumulate(x, cells, vals, origin, inv, dofs, coords, hc, acc, linear):
    """Accumulate the per-node moments of a particle → P1 projection into ``acc``.

    Average: columns ``[W, W*T (k)]``. Linear (``linear=True``): columns
    ``[W, count, W*h, W*dx (g), W*dx⊗dx (g(g+1)/2), W*T (k), W*T*dx (k*g)]``
    with ``W = N_i(x_p)`` and ``dx = x_p - x_i``.
    """
    n = x.shape[0]
    gdim = x.shape[1]
    k = vals.shape[1]
    nv = dofs.shape[1]
    lam = np.empty(4)
    dx = np.empty(3)
    ng = gdim * (gdim + 1) // 2
    for p in range(n):
        c = cells[p]
        _bary(x[p], c, origin, inv, lam)
        for i in range(nv):
            w = lam[i]
            if w < 0.0:
                w = 0.0
            elif w > 1.0:
                w = 1.0
            d = dofs[c, i]
            acc[d, 0] += w
            if not linear:
                for j in range(k):
                    acc[d, 1 + j] += w * vals[p, j]
                continue
            acc[d, 1] += 1.0
            acc[d, 2] += w * hc[c]
            for j in range(gdim):
                dx[j] = x[p, j] - coords[c, i, j]
                acc[d, 3 + j] += w * dx[j]
            o = 3 + gdim
            for a in range(gdim):
                for b in range(a, gdim):
                    acc[d, o] += w * dx[a] * dx[b]
                    o += 1
            o = 3 + gdim + ng
            for j in range(k):
                wt = w * vals[p, j]
                acc[d, o + j] += wt
                for a in range(gdim):
                    acc[d, o + k + j * gdim + a] += wt * dx[a]


@njit(cache=True)
def _inv_sym(C, gdim, Ci):
    """Inverse of a small symmetric positive matrix; returns its determinant."""
    if gdim == 1:
        det = C[0, 0]
        if det != 0.0:
            Ci[0, 0] = 1.0 / det
        return det
    if gdim == 2:
        det = C[0, 0] * C[1, 1] - C[0, 1] * C[1, 0]
        if det != 0.0:
            Ci[0, 0] = C[1, 1] / det
            Ci[1, 1] = C[0, 0] / det
            Ci[0, 1] = -C[0, 1] / det
            Ci[1, 0] = -C[1, 0] / det
        return det
    a = C
    det = (
        a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
        - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
        + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0])
    )
    if det != 0.0:
        Ci[0, 0] = (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) / det
        Ci[0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
        Ci[0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
        Ci[1, 0] = (a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]) / det
        Ci[1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
        Ci[1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
        Ci[2, 0] = (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]) / det
        Ci[2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
        Ci[2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return det


@njit(cache=True)
def project_solve(acc, gdim, k, linear, out, filled, fb, min_spread, max_extrap):
    """Nodal values from the accumulated moments (see :func:`project_accumulate`).

    Linear fit where it is well posed (at least ``gdim+1`` particles, the
    smallest eigenvalue-like measure ``det(C)^(1/g)`` of the weighted
    covariance above ``min_spread*h^2`` and the node within ``max_extrap``
    Mahalanobis radii of the particle centroid), the weighted average
    otherwise. Returns the number of nodes that used the fallback.
    """
    nd = acc.shape[0]
    ng = gdim * (gdim + 1) // 2
    C = np.zeros((3, 3))
    Ci = np.zeros((3, 3))
    xb = np.zeros(3)
    cov = np.zeros(3)
    nfb = 0
    for d in range(nd):
        W = acc[d, 0]
        fb[d] = False
        if W <= 0.0:
            filled[d] = False
            continue
        filled[d] = True
        if not linear:
            for j in range(k):
                out[d, j] = acc[d, 1 + j] / W
            continue
        o_t = 3 + gdim + ng
        ok = acc[d, 1] >= gdim + 1
        if ok:
            h = acc[d, 2] / W
            for a in range(gdim):
                xb[a] = acc[d, 3 + a] / W
            o = 3 + gdim
            for a in range(gdim):
                for b in range(a, gdim):
                    C[a, b] = acc[d, o] / W - xb[a] * xb[b]
                    C[b, a] = C[a, b]
                    o += 1
            det = _inv_sym(C, gdim, Ci)
            if det <= 0.0 or det ** (1.0 / gdim) < min_spread * h * h:
                ok = False
            else:
                m2 = 0.0
                for a in range(gdim):
                    for b in range(gdim):
                        m2 += xb[a] * Ci[a, b] * xb[b]
                if m2 > max_extrap * max_extrap:
                    ok = False
        fb[d] = not ok
        if not ok:
            nfb += 1
            for j in range(k):
                out[d, j] = acc[d, o_t + j] / W
            continue
        for j in range(k):
            tb = acc[d, o_t + j] / W
            for a in range(gdim):
                cov[a] = acc[d, o_t + k + j * gdim + a] / W - tb * xb[a]
            v = tb
            for a in range(gdim):
                ba = 0.0
                for b in range(gdim):
                    ba += Ci[a, b] * cov[b]
                v -= ba * xb[a]
            out[d, j] = v
    return nfb


@njit(cache=True)
def neighbour_fill_accumulate(dofs, n_owned, filled, vals, acc):
    """For every empty node, sum the values of filled nodes sharing an owned cell."""
    nv = dofs.shape[1]
    k = vals.shape[1]
    for c in range(n_owned):
        for i in range(nv):
            di = dofs[c, i]
            if filled[di]:
                continue
            for m in range(nv):
                dm = dofs[c, m]
                if filled[dm]:
                    acc[di, 0] += 1.0
                    for j in range(k):
                        acc[di, 1 + j] += vals[dm, j]


@njit(cache=True)
def counting_sort(cells, ncells):
    """Stable counting sort by cell: ``(order, offsets)``."""
    n = cells.shape[0]
    counts = np.zeros(ncells + 1, dtype=np.int64)
    for p in range(n):
        counts[cells[p] + 1] += 1
    for c in range(ncells):
        counts[c + 1] += counts[c]
    pos = counts[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for p in range(n):
        c = cells[p]
        order[pos[c]] = p
        pos[c] += 1
    return order, counts


@njit(cache=True)
def _mix64(z):
    """splitmix64 finaliser on uint64."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def _uniform(state):
    """Next uniform in [0, 1) of a splitmix64 stream; returns ``(u, state)``."""
    state = state + np.uint64(0x9E3779B97F4A7C15)
    z = _mix64(state)
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0), state


@njit(cache=True)
def _sample_simplex(state, coords, c, out, u):
    """Uniform point of simplex ``c`` into ``out`` (sorted-uniform spacings)."""
    tdim = coords.shape[1] - 1
    gdim = coords.shape[2]
    for i in range(tdim):
        r, state = _uniform(state)
        u[i] = r
    # insertion sort of tdim <= 3 numbers
    for i in range(1, tdim):
        v = u[i]
        j = i - 1
        while j >= 0 and u[j] > v:
            u[j + 1] = u[j]
            j -= 1
        u[j + 1] = v
    for j in range(gdim):
        out[j] = 0.0
    prev = 0.0
    for i in range(tdim + 1):
        w = (u[i] if i < tdim else 1.0) - prev
        prev = u[i] if i < tdim else 1.0
        for j in range(gdim):
            out[j] += w * coords[c, i, j]
    return state


@njit(cache=True)
def seed_cells(cells, counts, keys, seed, coords):
    """``counts[i]`` uniform random points in each cell ``cells[i]``.

    The stream of cell ``i`` depends only on ``(seed, keys[i])``, so a
    partition-independent key (the input cell index) gives the same
    particles on any number of ranks.
    """
    total = 0
    for i in range(cells.shape[0]):
        total += counts[i]
    gdim = coords.shape[2]
    x = np.empty((total, gdim))
    out_c = np.empty(total, dtype=np.int32)
    u = np.empty(4)
    pt = np.empty(3)
    k = 0
    for i in range(cells.shape[0]):
        state = _mix64(np.uint64(seed) * np.uint64(0x9E3779B97F4A7C15) + np.uint64(keys[i]))
        for _ in range(counts[i]):
            state = _sample_simplex(state, coords, cells[i], pt, u)
            for j in range(gdim):
                x[k, j] = pt[j]
            out_c[k] = cells[i]
            k += 1
    return x, out_c


@njit(cache=True)
def _fit_eval(x, vals, idx, nidx, pt, out, gdim):
    """Weighted-free linear least-squares fit of ``vals[idx]`` evaluated at ``pt``.

    Returns ``True`` when the fit is well posed; ``out`` gets the values.
    """
    k = vals.shape[1]
    if nidx < gdim + 1:
        return False
    xb = np.zeros(3)
    for q in range(nidx):
        for a in range(gdim):
            xb[a] += x[idx[q], a]
    for a in range(gdim):
        xb[a] /= nidx
    C = np.zeros((3, 3))
    Ci = np.zeros((3, 3))
    tr = 0.0
    for q in range(nidx):
        for a in range(gdim):
            for b in range(gdim):
                C[a, b] += (x[idx[q], a] - xb[a]) * (x[idx[q], b] - xb[b]) / nidx
    for a in range(gdim):
        tr += C[a, a]
    det = _inv_sym(C, gdim, Ci)
    if tr <= 0.0 or det <= 0.0 or det ** (1.0 / gdim) < 1e-3 * tr / gdim:
        return False
    cov = np.zeros(3)
    for j in range(k):
        tb = 0.0
        for q in range(nidx):
            tb += vals[idx[q], j]
        tb /= nidx
        for a in range(gdim):
            cov[a] = 0.0
        for q in range(nidx):
            t = vals[idx[q], j] - tb
            for a in range(gdim):
                cov[a] += t * (x[idx[q], a] - xb[a]) / nidx
        v = tb
        for a in range(gdim):
            ba = 0.0
            for b in range(gdim):
                ba += Ci[a, b] * cov[b]
            v += ba * (pt[a] - xb[a])
        out[j] = v
    return True


@njit(cache=True)
def _idw_eval(x, vals, idx, nidx, pt, out, gdim):
    k = vals.shape[1]
    if nidx == 0:
        return False
    ws = 0.0
    for j in range(k):
        out[j] = 0.0
    for q in range(nidx):
        d2 = 0.0
        for a in range(gdim):
            d2 += (x[idx[q], a] - pt[a]) ** 2
        w = 1.0 / (d2 + 1e-300)
        ws += w
        for j in range(k):
            out[j] += w * vals[idx[q], j]
    for j in range(k):
        out[j] /= ws
    return True


@njit(cache=True)
def population_plan(offsets, n_owned, nmin, nmax, only):
    """Number of particles to add (``> 0``) or remove (``< 0``) per owned cell."""
    plan = np.zeros(n_owned, dtype=np.int64)
    for c in range(n_owned):
        if only.shape[0] > 0 and not only[c]:
            continue
        k = offsets[c + 1] - offsets[c]
        if k < nmin:
            plan[c] = nmin - k
        elif nmax > 0 and k > nmax:
            plan[c] = nmax - k
    return plan


@njit(cache=True)
def population_remove(x, order, offsets, plan, remove):
    """Mark the most crowded particles (smallest nearest-neighbour distance) of crowded cells."""
    gdim = x.shape[1]
    for c in range(plan.shape[0]):
        if plan[c] >= 0:
            continue
        a = offsets[c]
        b = offsets[c + 1]
        for _ in range(-plan[c]):
            worst = -1
            wd = np.inf
            for i in range(a, b):
                pi = order[i]
                if remove[pi]:
                    continue
                dmin = np.inf
                for m in range(a, b):
                    pm = order[m]
                    if pm == pi or remove[pm]:
                        continue
                    d2 = 0.0
                    for j in range(gdim):
                        d2 += (x[pi, j] - x[pm, j]) ** 2
                    if d2 < dmin:
                        dmin = d2
                if dmin < wd:
                    wd = dmin
                    worst = pi
            if worst >= 0:
                remove[worst] = True


@njit(cache=True)
def population_add(x, vals, order, offsets, plan, keys, seed, coords, nbr, use_values, ncand):
    """New particles for cells short of particles.

    Positions: best of ``ncand`` uniform candidates (farthest from the cell's
    particles). Values (when ``use_values``): linear least-squares fit of the
    particles of the cell, else of the cell and its facet neighbours, else
    inverse-distance weighting of those; ``src`` tells which (1 fit cell,
    2 fit patch, 3 idw, 0 none: caller falls back to the mesh).
    """
    gdim = coords.shape[2]
    k = vals.shape[1]
    nv = coords.shape[1]
    total = 0
    for c in range(plan.shape[0]):
        if plan[c] > 0:
            total += plan[c]
    nx = np.empty((total, gdim))
    ncell = np.empty(total, dtype=np.int32)
    nvals = np.zeros((total, k))
    src = np.zeros(total, dtype=np.int8)
    u = np.empty(4)
    cand = np.empty(3)
    best = np.empty(3)
    out = np.empty(k)
    maxp = 0
    for c in range(plan.shape[0]):
        m = offsets[c + 1] - offsets[c]
        if m > maxp:
            maxp = m
    idx = np.empty(maxp * (nv + 1) + 1, dtype=np.int64)
    q = 0
    for c in range(plan.shape[0]):
        if plan[c] <= 0:
            continue
        a = offsets[c]
        b = offsets[c + 1]
        state = _mix64(np.uint64(seed) * np.uint64(0xD1B54A32D192ED03) + np.uint64(keys[c]))
        for _ in range(plan[c]):
            bd = -1.0
            for _t in range(ncand):
                state = _sample_simplex(state, coords, c, cand, u)
                dmin = np.inf
                for i in range(a, b):
                    d2 = 0.0
                    for j in range(gdim):
                        d2 += (x[order[i], j] - cand[j]) ** 2
                    if d2 < dmin:
                        dmin = d2
                if dmin > bd:
                    bd = dmin
                    for j in range(gdim):
                        best[j] = cand[j]
            for j in range(gdim):
                nx[q, j] = best[j]
            ncell[q] = c
            if use_values:
                ni = 0
                for i in range(a, b):
                    idx[ni] = order[i]
                    ni += 1
                if _fit_eval(x, vals, idx, ni, best, out, gdim):
                    src[q] = 1
                else:
                    for f in range(nv):
                        cn = nbr[c, f]
                        if cn < 0 or cn >= plan.shape[0]:
                            continue
                        for i in range(offsets[cn], offsets[cn + 1]):
                            if ni < idx.shape[0]:
                                idx[ni] = order[i]
                                ni += 1
                    if _fit_eval(x, vals, idx, ni, best, out, gdim):
                        src[q] = 2
                    elif _idw_eval(x, vals, idx, ni, best, out, gdim):
                        src[q] = 3
                if src[q] > 0:
                    for j in range(k):
                        nvals[q, j] = out[j]
            q += 1
    return nx, ncell, nvals, src
