"""Numba kernels of the particle layer (no DOLFINx, no MPI, no Python objects).

Every kernel works on plain arrays of the cached mesh arrays (see
:class:`pfem2x.particles.pmesh.ParticleMesh`) and loops over particles or
cells in compiled code. All of them are written for any dimension 1..3 and
work with Numba 0.56 (Debian) and 0.68 (PyPI).

The public kernels take the mesh packed in one :class:`MeshArrays` tuple
(and a move its state and parameters as :class:`MoveState` and
:class:`MoveParams`); they unpack it and pass plain arrays to the private
loops. Keep it so: members of a tuple unpacked inside a looping kernel, and
arrays handed to inline helpers in a hot loop, are reference-counted in the
loop (atomic operations; measured 3-5x slower moves); arguments are borrowed.

Facet codes in ``nbr`` (cells, tdim+1): ``>= 0`` the neighbour cell (for a
periodic facet: the cell holding the image point), ``WALL = -1``,
``REMOTE = -2`` (beyond this rank's ghost layer, or a periodic image that is
not local), ``OUTFLOW = -3``. ``pshift`` (cells, tdim+1) is ``0`` or
``±(axis+1)``: crossing that facet shifts the point by ``∓period[axis]``.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np

from pfem2x.aot import njit

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

MeshArrays = namedtuple(
    "MeshArrays", ["origin", "inv", "coords", "h", "dofs", "nbr", "pshift", "period", "n_owned"]
)
MeshArrays.__doc__ = """The mesh as the kernels see it (local cells, owned then ghosts).

``origin (cells, gdim)`` vertex 0, ``inv (cells, tdim, gdim)`` inverse
affine maps (barycentrics ``lambda[1:] = inv @ (x - origin)``), ``coords
(cells, tdim+1, gdim)`` vertices, ``h (cells,)`` cell sizes, ``dofs (cells,
tdim+1)`` P1 dofs, ``nbr``/``pshift (cells, tdim+1)`` facet codes (module
docstring), ``period (gdim,)`` box lengths, ``n_owned`` owned cells.
"""

MoveState = namedtuple("MoveState", ["x", "cell", "t_left", "aux", "acc", "stage", "status"])
MoveState.__doc__ = """Per-particle state of a move (updated in place by :func:`advect_p1`).

``x (n, gdim)`` positions, ``cell (n,)`` cells, ``t_left (n,)`` time left on
the path (stage 0) or Newton iterations spent (stage 1), ``aux (n, gdim)``
accumulated displacement (stage 0) or the anchor ``y`` of eq. (2.10)
(stage 1), ``acc (n, k)`` source integral (per component), ``stage (n,)``, ``status (n,)`` int8.
"""

MoveParams = namedtuple(
    "MoveParams", ["dt", "theta", "courant", "gcourant", "nsub", "has_q", "blend"]
)
MoveParams.__doc__ = """Parameters of one move: step ``dt``, X-IVAS ``theta``, sub-step
limits ``courant`` and ``gcourant`` (or ``nsub > 0`` fixed sub-steps),
``has_q`` (a nodal source ``q (ndofs, k)`` is integrated along the path) and
``blend`` (the velocity and the source go linearly in time over the move: at
time ``s`` after its start ``un + (s/dt) du`` and ``q + (s/dt) dq``)."""


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def _facet_grad(inv, c, i, j, tdim):
    """Component ``j`` of the gradient of barycentric coordinate ``i`` in cell ``c``."""
    if i == 0:
        v = 0.0
        for k in range(tdim):
            v -= inv[c, k, j]
        return v
    return inv[c, i - 1, j]


# Scalar helpers shared by every walk and move (all dimensions, the 2D move
# included). ``dim`` (= tdim = gdim) selects the components: points are
# ``(x0, x1, x2)`` and barycentrics ``(l0, l1, l2, l3)``, those beyond ``dim``
# unused (zero). Scalars rather than small work arrays keep the hot loops in
# registers. These helpers are plain functions (left to LLVM to inline):
# inlining them at the Numba IR level into the inlined move loop made its
# compilation run out of memory.


@njit(cache=True, error_model="numpy")
def _bary_s(x0, x1, x2, c, origin, inv, dim):
    """Barycentric coordinates ``(l0, l1, l2, l3)`` of ``(x0, x1, x2)`` in cell ``c``."""
    d0 = x0 - origin[c, 0]
    if dim == 1:
        l1 = inv[c, 0, 0] * d0
        return 1.0 - l1, l1, 0.0, 0.0
    d1 = x1 - origin[c, 1]
    if dim == 2:
        l1 = inv[c, 0, 0] * d0 + inv[c, 0, 1] * d1
        l2 = inv[c, 1, 0] * d0 + inv[c, 1, 1] * d1
        return 1.0 - (l1 + l2), l1, l2, 0.0
    d2 = x2 - origin[c, 2]
    l1 = inv[c, 0, 0] * d0 + inv[c, 0, 1] * d1 + inv[c, 0, 2] * d2
    l2 = inv[c, 1, 0] * d0 + inv[c, 1, 1] * d1 + inv[c, 1, 2] * d2
    l3 = inv[c, 2, 0] * d0 + inv[c, 2, 1] * d1 + inv[c, 2, 2] * d2
    return 1.0 - (l1 + l2 + l3), l1, l2, l3


@njit(cache=True, error_model="numpy")
def _facet_grad_s(inv, c, i, dim):
    """Gradient ``(g0, g1, g2)`` of barycentric coordinate ``i`` in cell ``c``."""
    g1 = 0.0
    g2 = 0.0
    if i > 0:
        g0 = inv[c, i - 1, 0]
        if dim > 1:
            g1 = inv[c, i - 1, 1]
        if dim > 2:
            g2 = inv[c, i - 1, 2]
        return g0, g1, g2
    g0 = -inv[c, 0, 0]
    if dim > 1:
        g1 = -inv[c, 0, 1]
    if dim > 2:
        g2 = -inv[c, 0, 2]
    for k in range(1, dim):
        g0 -= inv[c, k, 0]
        if dim > 1:
            g1 -= inv[c, k, 1]
        if dim > 2:
            g2 -= inv[c, k, 2]
    return g0, g1, g2


@njit(cache=True, error_model="numpy")
def _project_s(x0, x1, x2, c, i, lam_i, inv, dim):
    """Move ``(x0, x1, x2)`` onto the plane ``lambda_i = EPS_IN`` of cell ``c``.

    Drops the overshoot ``lam_i < 0`` of a point beyond the facet (slip wall).
    """
    g0, g1, g2 = _facet_grad_s(inv, c, i, dim)
    n2 = g0 * g0
    if dim > 1:
        n2 += g1 * g1
    if dim > 2:
        n2 += g2 * g2
    f = (lam_i - EPS_IN) / n2
    x0 -= f * g0
    if dim > 1:
        x1 -= f * g1
    if dim > 2:
        x2 -= f * g2
    return x0, x1, x2


@njit(cache=True, error_model="numpy")
def _walk_s(x0, x1, x2, c, origin, inv, nbr, pshift, period, maxit, dim):
    """Walk from cell ``c`` to the cell containing ``(x0, x1, x2)``.

    Leaves each cell through its most negative barycentric facet. Walls
    project the point back inside (slip), periodic facets wrap it. Returns
    ``(x0, x1, x2, cell, status, l0, l1, l2, l3, s0, s1, s2)``: the point, its
    cell and walk status, its barycentrics in that cell (on success) and the
    periodic translation applied.
    """
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    l0 = 0.0
    l1 = 0.0
    l2 = 0.0
    l3 = 0.0
    for _ in range(maxit):
        l0, l1, l2, l3 = _bary_s(x0, x1, x2, c, origin, inv, dim)
        best = 0
        bv = l0
        if l1 < bv:
            bv = l1
            best = 1
        if dim > 1 and l2 < bv:
            bv = l2
            best = 2
        if dim > 2 and l3 < bv:
            bv = l3
            best = 3
        if bv >= -TOL:
            return x0, x1, x2, c, ST_OK, l0, l1, l2, l3, s0, s1, s2
        nb = nbr[c, best]
        if nb == WALL:
            x0, x1, x2 = _project_s(x0, x1, x2, c, best, bv, inv, dim)
            continue
        ps = pshift[c, best]
        if ps != 0:  # periodic facet: wrap to the image
            ax = abs(ps) - 1
            d = -period[ax] if ps > 0 else period[ax]
            if ax == 0:
                x0 += d
                s0 += d
            elif ax == 1:
                x1 += d
                s1 += d
            else:
                x2 += d
                s2 += d
        if nb >= 0:
            c = nb
            continue
        st = ST_OUTFLOW if nb == OUTFLOW else ST_REMOTE
        return x0, x1, x2, c, st, l0, l1, l2, l3, s0, s1, s2
    return x0, x1, x2, c, ST_FAIL, l0, l1, l2, l3, s0, s1, s2


@njit(cache=True, error_model="numpy")
def _min_facet_tri(l0, l1, l2):
    """The smallest of a triangle's barycentrics and its index, as :func:`_walk_s` picks it."""
    best = 0
    bv = l0
    if l1 < bv:
        bv = l1
        best = 1
    if l2 < bv:
        bv = l2
        best = 2
    return bv, best


@njit(cache=True, error_model="numpy", inline="always")
def walk(x, c, origin, inv, nbr, pshift, period, lam, shift, maxit):
    """Walk from cell ``c`` to the cell containing ``x`` (modified in place).

    :func:`_walk_s` on arrays: walls project ``x`` back inside (slip),
    periodic facets wrap ``x`` (the applied translation is added to
    ``shift``). Returns ``(cell, status)``; on success ``lam`` holds the
    barycentric coordinates of ``x`` in ``cell``.
    """
    dim = inv.shape[1]
    x1 = x[1] if dim > 1 else 0.0
    x2 = x[2] if dim > 2 else 0.0
    x0, x1, x2, c, st, l0, l1, l2, l3, s0, s1, s2 = _walk_s(
        x[0], x1, x2, c, origin, inv, nbr, pshift, period, maxit, dim
    )
    x[0] = x0
    lam[0] = l0
    lam[1] = l1
    shift[0] += s0
    if dim > 1:
        x[1] = x1
        lam[2] = l2
        shift[1] += s1
    if dim > 2:
        x[2] = x2
        lam[3] = l3
        shift[2] += s2
    return c, st


@njit(cache=True, error_model="numpy", inline="always")
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


@njit(cache=True, error_model="numpy", inline="always")
def _eval_scalar(vals, dofs, c, lam):
    v = 0.0
    for i in range(dofs.shape[1]):
        v += lam[i] * vals[dofs[c, i]]
    return v


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def grad_norms(vals, cells, M):
    """:func:`_grad_norm` for many cells."""
    return _grad_norms(vals, M.dofs, cells, M.inv)


@njit(cache=True, error_model="numpy")
def _grad_norms(vals, dofs, cells, inv):
    out = np.empty(cells.shape[0])
    for p in range(cells.shape[0]):
        out[p] = _grad_norm(vals, dofs, cells[p], inv)
    return out


@njit(cache=True, error_model="numpy")
def locate_many(x, cells, M, maxit):
    """Walk every point ``x[p]`` from ``cells[p]``; returns ``(cells, status, shifts)``.

    ``x`` is modified in place (walls, periodic wrap). Status as in :func:`walk`,
    with ``ST_GHOST`` for points found in a ghost cell.
    """
    return _locate_many(x, cells, M.origin, M.inv, M.nbr, M.pshift, M.period, M.n_owned, maxit)


@njit(cache=True, error_model="numpy")
def _locate_many(x, cells, origin, inv, nbr, pshift, period, n_owned, maxit):
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


@njit(cache=True, error_model="numpy")
def contains(x, cells, M, tol):
    """Whether each ``x[p]`` lies in ``cells[p]`` (barycentric tolerance ``tol``)."""
    return _contains(x, cells, M.origin, M.inv, tol)


@njit(cache=True, error_model="numpy")
def _contains(x, cells, origin, inv, tol):
    n = x.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    lam = np.empty(4)
    for p in range(n):
        c = cells[p]
        if c < 0:
            continue
        out[p] = _bary(x[p], c, origin, inv, lam) >= -tol
    return out


@njit(cache=True, error_model="numpy")
def clamp_into(x, cells, M):
    """Move each ``x[p]`` to the closest point of ``cells[p]`` in barycentric terms."""
    _clamp_into(x, cells, M.origin, M.inv, M.coords)


@njit(cache=True, error_model="numpy")
def _clamp_into(x, cells, origin, inv, coords):
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


WITHIN_MARGIN = 1.0  # new particle, cell fit: may leave the samples' range by this x range
FIT_MAX_EXTRAP = 6.0  # new particle: fits only up to this many Mahalanobis radii from the samples
THETA_MAXIT = 30  # Newton iterations of eq. (2.10) per particle and step, over all ranks


@njit(cache=True, error_model="numpy", inline="always")
def _newton_dir(r, c, un1, dofs, inv, a, out, m):
    """``out = (I - a G)^{-1} r`` with ``G`` the (constant) gradient of ``un1`` in cell ``c``.

    ``m`` is ``(3, 3)`` scratch. Returns False (``out = r``) when the matrix is
    near singular.
    """
    tdim = inv.shape[1]
    gdim = inv.shape[2]
    for j in range(gdim):
        for k in range(gdim):
            g = 0.0
            for i in range(tdim + 1):
                g += un1[dofs[c, i], j] * _facet_grad(inv, c, i, k, tdim)
            m[j, k] = -a * g
        m[j, j] += 1.0
    if gdim == 1:
        det = m[0, 0]
    elif gdim == 2:
        det = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
    else:
        c00 = m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1]
        c01 = m[1, 2] * m[2, 0] - m[1, 0] * m[2, 2]
        c02 = m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0]
        det = m[0, 0] * c00 + m[0, 1] * c01 + m[0, 2] * c02
    if tdim != gdim or abs(det) < 1e-6:
        for j in range(gdim):
            out[j] = r[j]
        return False
    if gdim == 1:
        out[0] = r[0] / det
    elif gdim == 2:
        out[0] = (m[1, 1] * r[0] - m[0, 1] * r[1]) / det
        out[1] = (m[0, 0] * r[1] - m[1, 0] * r[0]) / det
    else:  # adjugate (transposed cofactors) / det
        c10 = m[0, 2] * m[2, 1] - m[0, 1] * m[2, 2]
        c11 = m[0, 0] * m[2, 2] - m[0, 2] * m[2, 0]
        c12 = m[0, 1] * m[2, 0] - m[0, 0] * m[2, 1]
        c20 = m[0, 1] * m[1, 2] - m[0, 2] * m[1, 1]
        c21 = m[0, 2] * m[1, 0] - m[0, 0] * m[1, 2]
        c22 = m[0, 0] * m[1, 1] - m[0, 1] * m[1, 0]
        out[0] = (c00 * r[0] + c10 * r[1] + c20 * r[2]) / det
        out[1] = (c01 * r[0] + c11 * r[1] + c21 * r[2]) / det
        out[2] = (c02 * r[0] + c12 * r[1] + c22 * r[2]) / det
    return True


@njit(cache=True, error_model="numpy")
def theta_stage(
    xp, c, y, theta, dt, un1, dofs, origin, inv, nbr, pshift, period, lam, sh, hc, it0, w
):
    """Solve eq. (2.10), ``x = y + theta*dt*V^{n+1}(x)``, starting at ``xp`` in ``c``.

    Newton iterations with the cell gradient of ``V^{n+1}``: exact in one
    step when the new point stays in the cell (``V^{n+1}`` is linear there),
    so the solve also converges when ``theta*dt*|grad V|`` exceeds 1 and
    plain fixed-point iteration diverges. The iteration is stateless, so it
    can continue on another rank; ``it0`` iterations were already spent on
    this particle (the count travels with it and caps the total, so a
    particle cannot be passed between ranks for ever). ``y`` is shifted
    together with ``xp`` when the walk wraps. ``w`` is ``(6, 3)`` scratch.
    Returns ``(cell, status, iterations)``; after ``THETA_MAXIT`` iterations
    the last iterate is kept.
    """
    gdim = un1.shape[1]
    v = w[0]
    r = w[1]
    dx = w[2]
    m = w[3:6]
    it = it0
    a = theta * dt
    while it < THETA_MAXIT:
        _bary(xp, c, origin, inv, lam)
        _eval_vec(un1, dofs, c, lam, v, 1.0, False)
        for j in range(gdim):
            r[j] = y[j] + a * v[j] - xp[j]
        exact = _newton_dir(r, c, un1, dofs, inv, a, dx, m)
        d2 = 0.0
        for j in range(gdim):
            d2 += dx[j] ** 2
            xp[j] += dx[j]
            sh[j] = 0.0
        it += 1
        c2, s = walk(xp, c, origin, inv, nbr, pshift, period, lam, sh, 1000)
        for j in range(gdim):
            y[j] += sh[j]
        if s != ST_OK:
            return c2, s, it
        same = c2 == c
        c = c2
        if (exact and same) or d2 <= (1e-12 * hc[c]) ** 2:
            break
    return c, ST_OK, it


@njit(cache=True, error_model="numpy")
def advect_p1(P, un, un1, du, q, dq, S, M):
    """Fused X-IVAS move + locate of every unfinished particle (P1 velocity).

    Heun (RK2) sub-steps along the streamline of ``un`` (``(ndofs, gdim)``; the
    corrector's walk starts in the predictor's cell unless that walk wrapped),
    each of local Courant number ``courant`` and at most ``gcourant``
    times the inverse velocity-gradient norm of the cell (or ``dt/nsub``
    when ``nsub > 0``); then, when ``theta > 0``, the fixed point of eq. (2.10)
    with ``un1``. Along the path ``acc += int q dt`` (trapezoid per sub-step,
    each of the ``k`` components of ``q (ndofs, k)``) when ``has_q``. ``aux``
    holds the accumulated displacement (stage 0) or the anchor ``y`` (stage 1).
    Returns the number of sub-steps taken. With ``blend`` the velocity and the
    source at time ``s`` of the move are ``un + (s/dt) du`` and ``q + (s/dt) dq``
    (linear in time; ``theta`` is then 0).

    ``P`` is a :class:`MoveState` (updated in place), ``S`` a
    :class:`MoveParams`, ``M`` the :class:`MeshArrays`. One loop
    (:func:`_advect_p1_dim`) serves every dimension; triangles in 2D get it
    compiled for the constant ``dim = 2``. The move evaluates ``un``, ``du``, ``q``
    and ``dq`` from each cell's affine form (:func:`move_tables`, tabled once per call;
    :func:`advect_p1_tables` takes the tables made once for several calls).
    """
    return advect_p1_tables(P, un, un1, du, move_tables(un, du, q, dq, S, M), S, M)


@njit(cache=True, error_model="numpy")
def move_tables(un, du, q, dq, S, M):
    """The per-cell affine tables ``(au, adu, aq, adq)`` of a move's fields (:func:`affine_p1`).

    ``un``, ``du``, ``q`` and ``dq`` as :func:`advect_p1` takes them; a table the move does
    not use (``du`` without ``blend``, ``q`` without ``has_q``) is a placeholder. The
    tables depend on the fields and the mesh only: a move that goes on in further rounds
    (particles handed over between ranks) uses the same tables.
    """
    blend, has_q = S[6], S[5]
    dofs, inv = M[4], M[1]
    au = affine_p1(un, dofs, inv)
    adu = affine_p1(du, dofs, inv) if blend else _no_table(du, inv)
    aq = affine_p1(q, dofs, inv) if has_q else _no_table(q, inv)
    adq = affine_p1(dq, dofs, inv) if has_q and blend else _no_table(dq, inv)
    return au, adu, aq, adq


@njit(cache=True, error_model="numpy")
def advect_p1_tables(P, un, un1, du, T, S, M):
    """:func:`advect_p1` with the fields' tables ``T = (au, adu, aq, adq)`` of
    :func:`move_tables` (the nodal ``un`` and ``du`` give the cells' gradient rates)."""
    x, cell, t_left, aux, acc, stage, status = P
    dt, theta, courant, gcourant, nsub, has_q, blend = S
    origin, inv, _, hc, dofs, nbr, pshift, period, n_owned = M
    au, adu, aq, adq = T
    if x.shape[1] == 2 and inv.shape[1] == 2:
        return _advect_p1_tri(
            x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
            gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
            au, adu, aq, adq,
        )  # fmt: skip
    return _advect_p1_any(
        x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
        gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
        au, adu, aq, adq,
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def affine_p1(vals, dofs, inv):
    """Each cell's piece of a P1 field ``vals (ndofs, k)`` as an affine function.

    Returns ``A (cells, k, dim + 1)``: ``A[c, j, 0]`` is component ``j`` at the cell's
    vertex 0 (``origin[c]``) and ``A[c, j, 1 + b]`` its derivative along axis ``b``, so
    that the field at ``x`` in ``c`` is ``A[c, j, 0] + sum_b A[c, j, 1 + b] (x_b -
    origin[c, b])`` (:func:`_eval_a`): the same function as the barycentric sum
    ``sum_i lambda_i vals[dofs[c, i], j]``, its value at ``x`` by three products instead
    of the barycentrics first, which shortens the chain of dependent operations of a
    move's sub-step.
    """
    nc = dofs.shape[0]
    k = vals.shape[1]
    dim = inv.shape[1]
    if dim == 2 and dofs.shape[1] == 3:
        return _affine_p1_tri(vals, dofs, inv)
    A = np.empty((nc, k, dim + 1))
    for c in range(nc):
        d0 = dofs[c, 0]
        for j in range(k):
            v0 = vals[d0, j]
            A[c, j, 0] = v0
            for b in range(dim):
                g = 0.0
                for i in range(dim):
                    g += (vals[dofs[c, i + 1], j] - v0) * inv[c, i, b]
                A[c, j, 1 + b] = g
    return A


@njit(cache=True, error_model="numpy")
def _affine_p1_tri(vals, dofs, inv):
    """:func:`affine_p1` on triangles, the loops over the axes written out (the same
    operations, the sums from 0.0 included: its tables to the bit, 2.4 times as fast)."""
    k = vals.shape[1]
    A = np.empty((dofs.shape[0], k, 3))
    for c in range(dofs.shape[0]):
        d0, d1, d2 = dofs[c, 0], dofs[c, 1], dofs[c, 2]
        i00, i01, i10, i11 = inv[c, 0, 0], inv[c, 0, 1], inv[c, 1, 0], inv[c, 1, 1]
        for j in range(k):
            v0 = vals[d0, j]
            e1 = vals[d1, j] - v0
            e2 = vals[d2, j] - v0
            A[c, j, 0] = v0
            g = 0.0
            g += e1 * i00
            g += e2 * i10
            A[c, j, 1] = g
            g = 0.0
            g += e1 * i01
            g += e2 * i11
            A[c, j, 2] = g
    return A


@njit(cache=True, error_model="numpy")
def _no_table(vals, inv):
    """A placeholder for :func:`affine_p1`'s table of a field the move does not use."""
    return np.zeros((1, vals.shape[1], inv.shape[1] + 1))


@njit(cache=True, error_model="numpy")
def _eval_a(A, j, c, x0, x1, x2, origin, dim):
    """Component ``j`` at ``(x0, x1, x2)`` in cell ``c`` of a field tabled by :func:`affine_p1`."""
    v = A[c, j, 0] + A[c, j, 1] * (x0 - origin[c, 0])
    if dim > 1:
        v += A[c, j, 2] * (x1 - origin[c, 1])
    if dim > 2:
        v += A[c, j, 3] * (x2 - origin[c, 2])
    return v


@njit(cache=True, error_model="numpy")
def _grad_norm_s(un, d0, d1, d2, d3, c, inv, dim):
    """:func:`_grad_norm` of a P1 vector field ``un (ndofs, dim)`` on dofs ``d`` of cell ``c``."""
    gs = 0.0
    for k in range(dim):
        for b in range(dim):
            g = -inv[c, 0, b]
            for i in range(1, dim):
                g -= inv[c, i, b]
            gv = un[d0, k] * g + un[d1, k] * inv[c, 0, b]
            if dim > 1:
                gv += un[d2, k] * inv[c, 1, b]
            if dim > 2:
                gv += un[d3, k] * inv[c, 2, b]
            gs += gv * gv
    return np.sqrt(gs)


@njit(cache=True, error_model="numpy")
def _grad_norm_end_s(un, du, d0, d1, d2, d3, c, inv, dim):
    """:func:`_grad_norm_s` of ``un + du`` (a move's velocity at its end, ``blend``)."""
    gs = 0.0
    for k in range(dim):
        for b in range(dim):
            g = -inv[c, 0, b]
            for i in range(1, dim):
                g -= inv[c, i, b]
            gv = (un[d0, k] + du[d0, k]) * g + (un[d1, k] + du[d1, k]) * inv[c, 0, b]
            if dim > 1:
                gv += (un[d2, k] + du[d2, k]) * inv[c, 1, b]
            if dim > 2:
                gv += (un[d3, k] + du[d3, k]) * inv[c, 2, b]
            gs += gv * gv
    return np.sqrt(gs)


@njit(cache=True, error_model="numpy")
def _gradient_rates(un, du, dofs, inv, gcourant, blend, nsub, n):
    """Each triangle's sub-step rate from the velocity gradient, or an empty array.

    ``max(|grad un|, |grad (un + du)|) / gcourant`` (the second with ``blend``): what
    :func:`_path_tri` would compute at each sub-step in the cell, the same to the bit,
    once per move. Empty (computed per sub-step) for fixed sub-steps (``nsub > 0``),
    ``gcourant = 0`` or fewer particles ``n`` than cells.
    """
    ncells = dofs.shape[0]
    if nsub > 0 or not gcourant > 0.0 or n < ncells:
        return np.zeros(0)
    rate = np.empty(ncells)
    for c in range(ncells):
        d0 = dofs[c, 0]
        d1 = dofs[c, 1]
        d2 = dofs[c, 2]
        g = _grad_norm_s(un, d0, d1, d2, 0, c, inv, 2) / gcourant
        if blend:
            ge = _grad_norm_end_s(un, du, d0, d1, d2, 0, c, inv, 2) / gcourant
            if ge > g:
                g = ge
        rate[c] = g
    return rate


# Deliberately two entry points of one loop: _advect_p1_tri passes dim as the literal 2 so
# numba compiles the 2D loop without the other dimensions' branches; _advect_p1_any reads it.
@njit(cache=True, error_model="numpy")
def _advect_p1_tri(
    x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
    gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
    au, adu, aq, adq,
):  # fmt: skip
    """:func:`advect_p1` for triangles in 2D (:func:`_advect_p1_dim` for a constant ``dim = 2``).

    The regular sub-steps go first (:func:`_path_tri`); :func:`_advect_p1_dim` then
    finishes every particle from where it left it (those whose path ended there with
    ``theta = 0`` are done already).
    """
    fast = _path_tri(
        x, cell, t_left, aux, acc, stage, status, dt, theta, un, has_q, courant, gcourant,
        nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend, au, adu, aq, adq,
    )  # fmt: skip
    return fast + _advect_p1_dim(
        x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
        gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
        au, adu, aq, adq, 2,
    )  # fmt: skip


@njit(cache=True, error_model="numpy")
def _path_tri(x, cell, t_left, aux, acc, stage, status, dt, theta, un, has_q, courant,
              gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
              au, adu, aq, adq):  # fmt: skip
    """The regular path sub-steps of every particle in stage 0 (triangles, 2D).

    Each particle's sub-steps are those of :func:`_advect_p1_dim`, operation for
    operation, with the particle in scalars and no retry branch. A particle stops
    at the end of its path or before its first sub-step that is not regular (a
    walk that does not end inside a local cell); its state (position, cell, time
    left, displacement, source integral) is written back for
    :func:`_advect_p1_dim`, which redoes that sub-step and finishes the particle.
    A particle at the end of its path with ``theta = 0`` is finished here as
    :func:`_advect_p1_dim` would (no time left, done, its status), so that loop
    passes over it. Returns the sub-steps taken.

    Most walks of a sub-step end in the cell they start in or in its neighbour
    across the facet of the most negative barycentric: the loop tests those two
    cells itself and calls :func:`_walk_s` (from the neighbour) only for the other
    walks (a wall, a periodic facet, two or more crossings). A call of
    :func:`_walk_s` passes every mesh array and returns its result through memory,
    and LLVM does not inline it; the result is :func:`_walk_s`'s to the bit (the
    same barycentrics, facets and cells).
    """
    n = x.shape[0]
    kq = aq.shape[1]
    ak = np.zeros(kq)
    tol = 1e-14 * dt
    nsteps = 0
    t0 = t1 = 0.0  # the time fractions of a sub-step's ends (blend)
    z0 = z1 = 0.0  # the change of the velocity over the move at a sub-step's start (blend)
    grate = _gradient_rates(un, du, dofs, inv, gcourant, blend, nsub, n)
    mfirst = float(nsub) if nsub > 0 else 1.0  # the guess of a path's first sub-step count
    for p in range(n):
        if stage[p] != STAGE_PATH or not t_left[p] > tol:
            continue
        c = cell[p]
        p0 = x[p, 0]
        p1 = x[p, 1]
        tl = t_left[p]
        a0 = aux[p, 0]
        a1 = aux[p, 1]
        if has_q:
            for j in range(kq):
                ak[j] = acc[p, j]
        mg = mfirst
        first = True
        ok = True
        while True:
            v0 = _eval_a(au, 0, c, p0, p1, 0.0, origin, 2)
            v1 = _eval_a(au, 1, c, p0, p1, 0.0, origin, 2)
            if blend:
                t0 = (dt - tl) / dt
                z0 = _eval_a(adu, 0, c, p0, p1, 0.0, origin, 2)
                z1 = _eval_a(adu, 1, c, p0, p1, 0.0, origin, 2)
                v0 += t0 * z0
                v1 += t0 * z1
            # the sub-step's length h = tl / m: the count m of sub-steps left is mostly the
            # last one's less one (or, at a path's start, the previous particle's), so that
            # length goes first and the position's chain need not wait for m
            hg = tl / mg
            if nsub > 0:
                h = dt / nsub
                m = np.ceil(tl / h - 1e-9)
                if m < 1.0:
                    m = 1.0
            else:
                sp = v0 * v0 + v1 * v1
                if blend:  # the speed at the move's end here too
                    y0 = v0 + (1.0 - t0) * z0
                    y1 = v1 + (1.0 - t0) * z1
                    sq = y0 * y0 + y1 * y1
                    if sq > sp:
                        sp = sq
                rate = np.sqrt(sp) / (courant * hc[c])
                if grate.shape[0] > 0:
                    gr = grate[c]
                    if gr > rate:
                        rate = gr
                elif gcourant > 0.0:
                    d0 = dofs[c, 0]
                    d1 = dofs[c, 1]
                    d2 = dofs[c, 2]
                    gr = _grad_norm_s(un, d0, d1, d2, 0, c, inv, 2) / gcourant
                    if gr > rate:
                        rate = gr
                    if blend:
                        gr = _grad_norm_end_s(un, du, d0, d1, d2, 0, c, inv, 2) / gcourant
                        if gr > rate:
                            rate = gr
                m = np.ceil(tl * rate)
                if m < 1.0:
                    m = 1.0
            if m == mg:  # then hg is tl / m
                h = hg
            else:
                h = tl / m
                # a store, so that LLVM keeps this a branch (predicted) and does not make
                # h a select of both, which waits for m (measured 20-28 % slower moves)
                t_left[p] = tl
            if first:
                mfirst = m
                first = False
            mg = m - 1.0
            if blend:
                t1 = (dt - tl + h) / dt
            # the predictor's walk: its start cell and that cell's neighbour here, the rest
            # by _walk_s (from that neighbour); the same result to the bit. Written out
            # here and for the corrector: a helper that returns the cell and a flag,
            # inlined by LLVM, made the loop 15 % slower (a saved Rayleigh-Taylor move)
            r0 = p0 + h * v0
            r1 = p1 + h * v1
            cm = c
            m0, m1, m2, _m3 = _bary_s(r0, r1, 0.0, cm, origin, inv, 2)
            bv, best = _min_facet_tri(m0, m1, m2)
            s = ST_OK
            ps0 = ps1 = 0.0
            if bv < -TOL and nbr[cm, best] >= 0 and pshift[cm, best] == 0:
                cm = nbr[cm, best]
                m0, m1, m2, _m3 = _bary_s(r0, r1, 0.0, cm, origin, inv, 2)
                bv, best = _min_facet_tri(m0, m1, m2)
            if not bv >= -TOL:
                r0, r1, _r2, cm, s, m0, m1, m2, _m3, ps0, ps1, _s2 = _walk_s(
                    r0, r1, 0.0, cm, origin, inv, nbr, pshift, period, 1000, 2
                )
            ok = s == ST_OK
            if not ok:
                break
            w0 = _eval_a(au, 0, cm, r0, r1, 0.0, origin, 2)
            w1 = _eval_a(au, 1, cm, r0, r1, 0.0, origin, 2)
            if blend:
                w0 += t1 * _eval_a(adu, 0, cm, r0, r1, 0.0, origin, 2)
                w1 += t1 * _eval_a(adu, 1, cm, r0, r1, 0.0, origin, 2)
            # the corrector's walk (as the predictor's) from the predictor's cell, unless
            # that walk wrapped
            cs = cm if ps0 == 0.0 and ps1 == 0.0 else c
            n0 = p0 + 0.5 * h * (v0 + w0)
            n1 = p1 + 0.5 * h * (v1 + w1)
            cn = cs
            k0, k1, k2, _k3 = _bary_s(n0, n1, 0.0, cn, origin, inv, 2)
            bv, best = _min_facet_tri(k0, k1, k2)
            s = ST_OK
            s0 = s1 = 0.0
            if bv < -TOL and nbr[cn, best] >= 0 and pshift[cn, best] == 0:
                cn = nbr[cn, best]
                k0, k1, k2, _k3 = _bary_s(n0, n1, 0.0, cn, origin, inv, 2)
                bv, best = _min_facet_tri(k0, k1, k2)
            if not bv >= -TOL:
                n0, n1, _n2, cn, s, k0, k1, k2, _k3, s0, s1, _s2 = _walk_s(
                    n0, n1, 0.0, cn, origin, inv, nbr, pshift, period, 1000, 2
                )
            ok = s == ST_OK
            if not ok:
                break
            if has_q:
                for j in range(kq):
                    qv = _eval_a(aq, j, c, p0, p1, 0.0, origin, 2)
                    qe = _eval_a(aq, j, cn, n0, n1, 0.0, origin, 2)
                    if blend:
                        qv += t0 * _eval_a(adq, j, c, p0, p1, 0.0, origin, 2)
                        qe += t1 * _eval_a(adq, j, cn, n0, n1, 0.0, origin, 2)
                    ak[j] += 0.5 * h * (qv + qe)
            a0 += n0 - s0 - p0
            a1 += n1 - s1 - p1
            p0 = n0
            p1 = n1
            tl -= h
            c = cn
            nsteps += 1
            if not tl > tol:
                break
        x[p, 0] = p0
        x[p, 1] = p1
        cell[p] = c
        t_left[p] = tl
        if ok and theta == 0.0:  # the path's end: done (as _advect_p1_dim)
            t_left[p] = 0.0
            stage[p] = STAGE_DONE
            status[p] = ST_GHOST if c >= n_owned else ST_OK
        aux[p, 0] = a0
        aux[p, 1] = a1
        if has_q:
            for j in range(kq):
                acc[p, j] = ak[j]
    return nsteps


@njit(cache=True, error_model="numpy")
def _advect_p1_any(
    x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
    gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
    au, adu, aq, adq,
):  # fmt: skip
    """:func:`advect_p1` in any dimension (:func:`_advect_p1_dim` for a run-time ``dim``)."""
    return _advect_p1_dim(
        x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
        gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
        au, adu, aq, adq, inv.shape[1],
    )  # fmt: skip


@njit(cache=True, error_model="numpy", inline="always")
def _advect_p1_dim(
    x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, has_q, courant,
    gcourant, nsub, origin, inv, nbr, pshift, period, hc, dofs, n_owned, du, blend,
    au, adu, aq, adq, dim,
):  # fmt: skip
    """The loop of :func:`advect_p1` (inlined: a constant ``dim`` folds its branches).

    The sub-steps keep the particle, its velocities and barycentrics in
    scalars (:func:`_walk_s`); the theta stage works on small arrays.
    """
    n = x.shape[0]
    xp = np.empty(3)
    lam = np.empty(4)
    sh = np.zeros(3)
    y = np.empty(3)
    wth = np.empty((6, 3))
    kq = aq.shape[1]
    ak = np.zeros(kq)  # the source integral of the particle (k components)
    qv = np.zeros(kq)  # the source at the start of a sub-step
    t0 = t1 = 0.0  # the time fractions of a sub-step's ends (blend)
    z0 = z1 = z2 = 0.0  # the change of the velocity over the move at a sub-step's start
    nsteps = 0
    for p in range(n):
        if stage[p] == STAGE_DONE:
            continue
        c = cell[p]
        p0 = x[p, 0]
        p1 = x[p, 1] if dim > 1 else 0.0
        p2 = x[p, 2] if dim > 2 else 0.0
        st = ST_OK
        tl = t_left[p]
        if has_q:
            for j in range(kq):
                ak[j] = acc[p, j]
        if stage[p] == STAGE_PATH:
            a0 = aux[p, 0]
            a1 = aux[p, 1] if dim > 1 else 0.0
            a2 = aux[p, 2] if dim > 2 else 0.0
            while tl > 1e-14 * dt:
                v0 = _eval_a(au, 0, c, p0, p1, p2, origin, dim)
                v1 = _eval_a(au, 1, c, p0, p1, p2, origin, dim) if dim > 1 else 0.0
                v2 = _eval_a(au, 2, c, p0, p1, p2, origin, dim) if dim > 2 else 0.0
                if blend:
                    t0 = (dt - tl) / dt
                    z0 = _eval_a(adu, 0, c, p0, p1, p2, origin, dim)
                    z1 = _eval_a(adu, 1, c, p0, p1, p2, origin, dim) if dim > 1 else 0.0
                    z2 = _eval_a(adu, 2, c, p0, p1, p2, origin, dim) if dim > 2 else 0.0
                    v0 += t0 * z0
                    v1 += t0 * z1
                    v2 += t0 * z2
                if nsub > 0:
                    h = dt / nsub
                    m = np.ceil(tl / h - 1e-9)
                    if m < 1.0:
                        m = 1.0
                    h = tl / m
                else:
                    sp = v0 * v0
                    if dim > 1:
                        sp += v1 * v1
                    if dim > 2:
                        sp += v2 * v2
                    if blend:  # the speed at the move's end here too
                        y0 = v0 + (1.0 - t0) * z0
                        y1 = v1 + (1.0 - t0) * z1
                        y2 = v2 + (1.0 - t0) * z2
                        sq = y0 * y0
                        if dim > 1:
                            sq += y1 * y1
                        if dim > 2:
                            sq += y2 * y2
                        if sq > sp:
                            sp = sq
                    rate = np.sqrt(sp) / (courant * hc[c])
                    if gcourant > 0.0:
                        d0 = dofs[c, 0]
                        d1 = dofs[c, 1]
                        d2 = dofs[c, 2] if dim > 1 else 0
                        d3 = dofs[c, 3] if dim > 2 else 0
                        gr = _grad_norm_s(un, d0, d1, d2, d3, c, inv, dim) / gcourant
                        if gr > rate:
                            rate = gr
                        if blend:
                            gr = _grad_norm_end_s(un, du, d0, d1, d2, d3, c, inv, dim) / gcourant
                            if gr > rate:
                                rate = gr
                    m = np.ceil(tl * rate)
                    if m < 1.0:
                        m = 1.0
                    h = tl / m
                # midpoint (predictor) with retries when it leaves the local mesh
                ok = False
                s = ST_OK
                cm = c
                m0 = 0.0
                m1 = 0.0
                m2 = 0.0
                m3 = 0.0
                ps0 = ps1 = ps2 = 0.0
                for _r in range(12):
                    mx0, mx1, mx2, cm, s, m0, m1, m2, m3, ps0, ps1, ps2 = _walk_s(
                        p0 + h * v0, p1 + h * v1, p2 + h * v2, c, origin, inv, nbr, pshift,
                        period, 1000, dim,
                    )  # fmt: skip
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
                    if has_q:
                        for j in range(kq):
                            qv[j] = _eval_a(aq, j, c, p0, p1, p2, origin, dim)
                            if blend:
                                qv[j] += t0 * _eval_a(adq, j, c, p0, p1, p2, origin, dim)
                    n0, n1, n2, cn, s, l0, l1, l2, l3, s0, s1, s2 = _walk_s(
                        p0 + h * v0, p1 + h * v1, p2 + h * v2, c, origin, inv, nbr, pshift,
                        period, 1000, dim,
                    )  # fmt: skip
                    if has_q:
                        for j in range(kq):
                            ak[j] += h * qv[j]
                    a0 += n0 - s0 - p0
                    a1 += n1 - s1 - p1
                    a2 += n2 - s2 - p2
                    p0 = n0
                    p1 = n1
                    p2 = n2
                    tl -= h
                    nsteps += 1
                    c = cn
                    st = s if s != ST_OK else (ST_GHOST if c >= n_owned else ST_OK)
                    if st == ST_OK:
                        continue
                    break
                w0 = _eval_a(au, 0, cm, mx0, mx1, mx2, origin, dim)
                w1 = _eval_a(au, 1, cm, mx0, mx1, mx2, origin, dim) if dim > 1 else 0.0
                w2 = _eval_a(au, 2, cm, mx0, mx1, mx2, origin, dim) if dim > 2 else 0.0
                if blend:
                    t1 = (dt - tl + h) / dt
                    w0 += t1 * _eval_a(adu, 0, cm, mx0, mx1, mx2, origin, dim)
                    if dim > 1:
                        w1 += t1 * _eval_a(adu, 1, cm, mx0, mx1, mx2, origin, dim)
                    if dim > 2:
                        w2 += t1 * _eval_a(adu, 2, cm, mx0, mx1, mx2, origin, dim)
                if has_q:
                    for j in range(kq):
                        qv[j] = _eval_a(aq, j, c, p0, p1, p2, origin, dim)
                        if blend:
                            qv[j] += t0 * _eval_a(adq, j, c, p0, p1, p2, origin, dim)
                # the corrector's walk from the predictor's cell (unless that walk wrapped)
                cs = cm if ps0 == 0.0 and ps1 == 0.0 and ps2 == 0.0 else c
                n0, n1, n2, cn, s, l0, l1, l2, l3, s0, s1, s2 = _walk_s(
                    p0 + 0.5 * h * (v0 + w0), p1 + 0.5 * h * (v1 + w1), p2 + 0.5 * h * (v2 + w2),
                    cs, origin, inv, nbr, pshift, period, 1000, dim,
                )  # fmt: skip
                if has_q and s == ST_OK:
                    for j in range(kq):
                        qe = _eval_a(aq, j, cn, n0, n1, n2, origin, dim)
                        if blend:
                            qe += t1 * _eval_a(adq, j, cn, n0, n1, n2, origin, dim)
                        ak[j] += 0.5 * h * (qv[j] + qe)
                elif has_q and blend:  # the end's cell is not local: its time at the start
                    for j in range(kq):
                        qe = _eval_a(aq, j, c, p0, p1, p2, origin, dim)
                        qe += t1 * _eval_a(adq, j, c, p0, p1, p2, origin, dim)
                        ak[j] += 0.5 * h * (qv[j] + qe)
                elif has_q:
                    for j in range(kq):
                        ak[j] += h * qv[j]
                a0 += n0 - s0 - p0
                a1 += n1 - s1 - p1
                a2 += n2 - s2 - p2
                p0 = n0
                p1 = n1
                p2 = n2
                tl -= h
                nsteps += 1
                c = cn
                if s != ST_OK:
                    st = s
                    break
            aux[p, 0] = a0
            if dim > 1:
                aux[p, 1] = a1
            if dim > 2:
                aux[p, 2] = a2
            if st == ST_OK:
                tl = 0.0
                if theta > 0.0:
                    stage[p] = STAGE_THETA
                    aux[p, 0] = p0 - theta * aux[p, 0]
                    if dim > 1:
                        aux[p, 1] = p1 - theta * aux[p, 1]
                    if dim > 2:
                        aux[p, 2] = p2 - theta * aux[p, 2]
                else:
                    stage[p] = STAGE_DONE
        if st == ST_OK and stage[p] == STAGE_THETA:
            xp[0] = p0
            xp[1] = p1
            xp[2] = p2
            for j in range(dim):
                y[j] = aux[p, j]
            its0 = int(tl)
            c, st, its = theta_stage(
                xp, c, y, theta, dt, un1, dofs, origin, inv, nbr, pshift, period, lam, sh, hc,
                its0, wth,
            )  # fmt: skip
            tl = float(its)  # in stage 1, t_left counts Newton iterations
            for j in range(dim):
                aux[p, j] = y[j]
            p0 = xp[0]
            p1 = xp[1]
            p2 = xp[2]
            if st == ST_OK:
                stage[p] = STAGE_DONE
        if st == ST_OK and c >= n_owned:
            st = ST_GHOST
        x[p, 0] = p0
        if dim > 1:
            x[p, 1] = p1
        if dim > 2:
            x[p, 2] = p2
        cell[p] = c
        t_left[p] = tl
        if has_q:
            for j in range(kq):
                acc[p, j] = ak[j]
        status[p] = st
    return nsteps


@njit(cache=True, error_model="numpy")
def evaluate_p1(x, cells, vals, M):
    """Values of a P1 field ``vals (ndofs, k)`` at the points ``x`` in ``cells``."""
    return _evaluate_p1(x, cells, vals, M.origin, M.inv, M.dofs)


@njit(cache=True, error_model="numpy")
def _evaluate_p1(x, cells, vals, origin, inv, dofs):
    if x.shape[1] == 2 and dofs.shape[1] == 3:
        return _evaluate_p1_tri(x, cells, vals, origin, inv, dofs)
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


@njit(cache=True, error_model="numpy")
def _evaluate_p1_tri(x, cells, vals, origin, inv, dofs):
    """:func:`evaluate_p1` for triangles in 2D (same operations, scalar registers)."""
    n = x.shape[0]
    k = vals.shape[1]
    out = np.empty((n, k))
    for p in range(n):
        c = cells[p]
        l0, l1, l2, _l3 = _bary_s(x[p, 0], x[p, 1], 0.0, c, origin, inv, 2)
        d0 = dofs[c, 0]
        d1 = dofs[c, 1]
        d2 = dofs[c, 2]
        for j in range(k):
            out[p, j] = l0 * vals[d0, j] + l1 * vals[d1, j] + l2 * vals[d2, j]
    return out


@njit(cache=True, error_model="numpy")
def project_accumulate(x, cells, vals, M, acc, linear):
    """Accumulate the per-node moments of a particle → P1 projection into ``acc``.

    Average: columns ``[W, W*T (k)]``. Linear (``linear=True``): columns
    ``[W, count, W*h, W*dx (g), W*dx⊗dx (g(g+1)/2), W*T (k), W*T*dx (k*g)]``
    with ``W = N_i(x_p)`` and ``dx = x_p - x_i``.
    """
    _project_accumulate(x, cells, vals, M.origin, M.inv, M.dofs, M.coords, M.h, acc, linear)


@njit(cache=True, error_model="numpy")
def _project_accumulate(x, cells, vals, origin, inv, dofs, coords, hc, acc, linear):
    if x.shape[1] == 2 and dofs.shape[1] == 3:
        _project_accumulate_tri(x, cells, vals, origin, inv, dofs, coords, hc, acc, linear)
        return
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


@njit(cache=True, error_model="numpy")
def project_accumulate_tri_many(x, cells, lin, avgs, M, acc):
    """:func:`project_accumulate` of several fields of 2D triangles in one pass.

    ``lin`` ``(n, k)``, ``k`` 1 or 2: a linear projection's columns, as
    :func:`project_accumulate` lays them out (``8 + 3 k``); then the weighted sums
    ``W*T`` of each array of ``avgs`` (a tuple of ``(n, k_f)`` arrays, an average
    projection each, whose ``W`` is column 0). Every column is summed in the order
    and with the operations of the single projections (their results to the bit).
    A particle's average values are copied to a buffer first: the tuple indexed in
    the loop over the cell's nodes made the pass 2.5 times as long.
    """
    origin, inv, dofs, coords, hc = M.origin, M.inv, M.dofs, M.coords, M.h
    two = lin.shape[1] == 2
    o0 = 10 if two else 9
    o_avg = 14 if two else 11
    nv = 0
    for f in range(len(avgs)):
        nv += avgs[f].shape[1]
    buf = np.empty(nv)
    for p in range(x.shape[0]):
        c, x0, x1, l0, l1, l2, hcc, t0, t1 = _linear_particle(x, cells, lin, p, origin, inv, hc)
        o = 0
        for f in range(len(avgs)):
            a = avgs[f]
            for j in range(a.shape[1]):
                buf[o] = a[p, j]
                o += 1
        for i in range(3):
            w = l0 if i == 0 else (l1 if i == 1 else l2)
            d = dofs[c, i]
            _node_moments(
                acc, d, w, x0 - coords[c, i, 0], x1 - coords[c, i, 1], hcc, t0, t1, two, o0
            )
            if w < 0.0:
                w = 0.0
            elif w > 1.0:
                w = 1.0
            for j in range(nv):
                acc[d, o_avg + j] += w * buf[j]


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _root(v, g):
    """``v ** (1 / g)`` for ``v > 0``: ``sqrt`` in 2D (the power costs half the solve)."""
    if g == 2:
        return np.sqrt(v)
    if g == 1:
        return v
    return v ** (1.0 / g)


@njit(cache=True, error_model="numpy")
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
            if det <= 0.0 or _root(det, gdim) < min_spread * h * h:
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def share_drop(cells, ncells, share):
    """Drop mask keeping a share of each cell's particles (in storage order).

    A particle of rank ``r`` among its cell's particles (storage order) is kept when
    ``r = 0`` or ``floor(r share) > floor((r - 1) share)``.
    """
    n = cells.shape[0]
    count = np.zeros(ncells, dtype=np.int64)
    drop = np.empty(n, dtype=np.bool_)
    for p in range(n):
        c = cells[p]
        r = count[c]
        count[c] = r + 1
        drop[p] = not (r == 0 or np.floor(r * share) > np.floor((r - 1) * share))
    return drop


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def chain_walk(ids, n_points):
    """Polylines of the segments ``ids (m, 2)`` (point ids ``< n_points``) that share ends.

    Returns ``(order, starts)``: the polylines one after another as indices into the
    segments' end points ``ids.ravel()`` (of a point, its last appearance), and each
    polyline's first place in ``order`` (one more: the end). The walk: the points in
    order of their first appearance, those at an open end (one segment) first, then
    all; from each point, while it has an unused segment, a polyline: the current
    point's first unused segment (in order of appearance) to its other end, until the
    current point has none left. Every segment is in one polyline.
    """
    m = ids.shape[0]
    ptr = np.zeros(n_points + 1, dtype=np.int64)
    for k in range(m):
        ptr[ids[k, 0] + 1] += 1
        ptr[ids[k, 1] + 1] += 1
    for i in range(n_points):
        ptr[i + 1] += ptr[i]
    pos = ptr[:-1].copy()
    inc = np.empty(2 * m, dtype=np.int64)
    where = np.empty(n_points, dtype=np.int64)
    appear = np.empty(n_points, dtype=np.int64)
    seen = np.zeros(n_points, dtype=np.bool_)
    n_seen = 0
    for k in range(m):
        for j in range(2):
            v = ids[k, j]
            inc[pos[v]] = k
            pos[v] += 1
            where[v] = 2 * k + j
            if not seen[v]:
                seen[v] = True
                appear[n_seen] = v
                n_seen += 1
    used = np.zeros(m, dtype=np.bool_)
    order = np.empty(2 * m + 1, dtype=np.int64)
    starts = np.empty(m + 1, dtype=np.int64)
    n_lines = 0
    n = 0
    for sweep in range(2):
        for a in range(n_seen):
            v0 = appear[a]
            if sweep == 0 and ptr[v0 + 1] - ptr[v0] != 1:
                continue
            while True:  # (a junction may start several polylines)
                free = False
                for q in range(ptr[v0], ptr[v0 + 1]):
                    if not used[inc[q]]:
                        free = True
                        break
                if not free:
                    break
                starts[n_lines] = n
                n_lines += 1
                order[n] = where[v0]
                n += 1
                v = v0
                while True:
                    k = -1
                    for q in range(ptr[v], ptr[v + 1]):
                        if not used[inc[q]]:
                            k = inc[q]
                            break
                    if k < 0:
                        break
                    used[k] = True
                    v = ids[k, 1] if ids[k, 0] == v else ids[k, 0]
                    order[n] = where[v]
                    n += 1
    starts[n_lines] = n
    return order[:n], starts[: n_lines + 1]


@njit(cache=True, error_model="numpy")
def entry_structure(rows, cols, E, n_rows):
    """The sparse structure of the element tensors ``E (n, nr, nc)`` at ``(rows, cols)``.

    ``rows (n, nr)`` and ``cols (n, nc)`` (int64) are each cell's row and column
    indices. Returns ``(indptr, indices, entry_rows, s_ptr, s_cell, s_val)``: the CSR
    structure of the matrix's distinct entries (rows ascending, each row's columns
    ascending; ``entry_rows`` the row of each entry), and for each distinct entry its
    contributions ``s_ptr[e]:s_ptr[e + 1]`` of ``s_cell`` (the cell) and ``s_val`` (the
    element value), cells ascending. The same as a stable sort of the keys
    ``row * n_cols + col`` of the element entries in their order (cell, row, column):
    a counting sort by row, then an insertion sort of each row's few entries by column.
    """
    n, nr = rows.shape
    nc = cols.shape[1]
    start = np.zeros(n_rows + 1, dtype=np.int64)
    for c in range(n):
        for i in range(nr):
            start[rows[c, i] + 1] += nc
    for r in range(n_rows):
        start[r + 1] += start[r]
    total = start[n_rows]
    pos = start[:-1].copy()
    col = np.empty(total, dtype=np.int32)  # (local indices)
    cell = np.empty(total, dtype=np.int32)
    val = np.empty(total)
    for c in range(n):
        for i in range(nr):
            r = rows[c, i]
            for j in range(nc):
                p = pos[r]
                pos[r] += 1
                col[p] = cols[c, j]
                cell[p] = c
                val[p] = E[c, i, j]
    n_unique = 0
    for r in range(n_rows):
        a = start[r]
        for p in range(a + 1, start[r + 1]):  # stable: equal columns keep their order
            kc, kcell, kv = col[p], cell[p], val[p]
            q = p - 1
            while q >= a and col[q] > kc:
                col[q + 1] = col[q]
                cell[q + 1] = cell[q]
                val[q + 1] = val[q]
                q -= 1
            col[q + 1] = kc
            cell[q + 1] = kcell
            val[q + 1] = kv
        for p in range(a, start[r + 1]):
            if p == a or col[p] != col[p - 1]:
                n_unique += 1
    indptr = np.zeros(n_rows + 1, dtype=np.int64)
    indices = np.empty(n_unique, dtype=np.int64)
    entry_rows = np.empty(n_unique, dtype=np.int64)
    s_ptr = np.empty(n_unique + 1, dtype=np.int64)
    e = 0
    for r in range(n_rows):
        a = start[r]
        for p in range(a, start[r + 1]):
            if p == a or col[p] != col[p - 1]:
                indices[e] = col[p]
                entry_rows[e] = r
                s_ptr[e] = p
                e += 1
        indptr[r + 1] = e
    s_ptr[n_unique] = total
    return indptr, indices, entry_rows, s_ptr, cell, val


@njit(cache=True, error_model="numpy")
def is_identity(order):
    """Whether ``order`` is ``0, 1, ..., n - 1`` (stops at the first index out of place)."""
    for i in range(order.shape[0]):
        if order[i] != i:
            return False
    return True


@njit(cache=True, error_model="numpy")
def put_rows(src, rows, dst, col):
    """``dst[r, col:col + k] = src[r]`` for each row ``r`` of ``rows`` (``src``: ``(n, k)``).

    Population control's value table: numpy's ``dst[rows, col:col + k] = src[rows]``
    (an index array and a slice) took 2.4 times as long.
    """
    k = src.shape[1]
    for i in range(rows.shape[0]):
        r = rows[i]
        for j in range(k):
            dst[r, col + j] = src[r, j]


@njit(cache=True, error_model="numpy")
def gather_rows(src, idx, dst):
    """``dst[i] = src[idx[i]]`` for the rows of ``(rows, k)`` arrays (a particle reordering).

    Rows of 1, 2 and 3 values are copied written out: the loop over a row's ``k``
    values cost 4–7 times as much (a 650,000-particle field).
    """
    k = src.shape[1]
    if k == 1:
        for i in range(idx.shape[0]):
            dst[i, 0] = src[idx[i], 0]
    elif k == 2:
        for i in range(idx.shape[0]):
            j = idx[i]
            dst[i, 0] = src[j, 0]
            dst[i, 1] = src[j, 1]
    elif k == 3:
        for i in range(idx.shape[0]):
            j = idx[i]
            dst[i, 0] = src[j, 0]
            dst[i, 1] = src[j, 1]
            dst[i, 2] = src[j, 2]
    else:
        for i in range(idx.shape[0]):
            j = idx[i]
            for c in range(k):
                dst[i, c] = src[j, c]


@njit(cache=True, error_model="numpy")
def _mix64(z):
    """splitmix64 finaliser on uint64."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def _uniform(state):
    """Next uniform in [0, 1) of a splitmix64 stream; returns ``(u, state)``."""
    state = state + np.uint64(0x9E3779B97F4A7C15)
    z = _mix64(state)
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0), state


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def _fit_eval(x, vals, idx, nidx, pt, out, gdim):
    """Weighted-free linear least-squares fit of ``vals[idx]`` evaluated at ``pt``.

    Returns ``True`` when the fit is well posed; ``out`` gets the values.
    Ill posed: fewer than ``gdim + 1`` points, a nearly degenerate spread, or
    ``pt`` farther than ``FIT_MAX_EXTRAP`` Mahalanobis radii from the
    points' centroid (the fit's error there is that many times the values'
    noise: a new particle across a nearly collinear set of particles would
    get an extrapolated value far outside anything near it).
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
    dm2 = 0.0
    for a in range(gdim):
        for b in range(gdim):
            dm2 += (pt[a] - xb[a]) * Ci[a, b] * (pt[b] - xb[b])
    if dm2 > FIT_MAX_EXTRAP**2:
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


@njit(cache=True, error_model="numpy")
def _within(vals, idx, nidx, out):
    """Whether ``out`` lies within ``WITHIN_MARGIN`` ranges of ``vals[idx]`` (per component).

    A linear fit evaluated inside the convex hull of its points lies within
    their range; a little outside it (a new particle placed in the corner of
    a sparse cell) it may leave it by a fraction of the range. A cell fit
    that leaves it by more is replaced by the fit over the cell and its
    neighbours, which surround the new particle.
    """
    k = vals.shape[1]
    for j in range(k):
        lo = np.inf
        hi = -np.inf
        for q in range(nidx):
            v = vals[idx[q], j]
            lo = min(lo, v)
            hi = max(hi, v)
        pad = WITHIN_MARGIN * (hi - lo) + 1e-12 * max(abs(hi), abs(lo))
        if out[j] < lo - pad or out[j] > hi + pad:
            return False
    return True


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
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


@njit(cache=True, error_model="numpy")
def population_add(x, vals, order, offsets, plan, keys, seed, coords, nbr, use_values, ncand):
    """New particles for cells short of particles.

    Positions: best of ``ncand`` uniform candidates (farthest from the cell's
    particles). Values (when ``use_values``): linear least-squares fit of the
    particles of the cell if it stays near their range, else a fit of the
    cell and its facet neighbours, else (fits ill posed: too few points, too
    thin a spread, or too far an extrapolation) inverse-distance weighting
    of those; ``src`` tells which (1 fit cell,
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
                if _fit_eval(x, vals, idx, ni, best, out, gdim) and _within(vals, idx, ni, out):
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


@njit(cache=True, error_model="numpy")
def _project_accumulate_tri(x, cells, vals, origin, inv, dofs, coords, hc, acc, linear):
    """:func:`project_accumulate` for triangles in 2D (same operations, scalar registers)."""
    n = x.shape[0]
    k = vals.shape[1]
    if linear and k <= 2:
        _project_linear_tri(x, cells, vals, origin, inv, dofs, coords, hc, acc)
        return
    for p in range(n):
        c = cells[p]
        x0 = x[p, 0]
        x1 = x[p, 1]
        l0, l1, l2, _l3 = _bary_s(x0, x1, 0.0, c, origin, inv, 2)
        hcc = hc[c]
        for i in range(3):
            w = l0 if i == 0 else (l1 if i == 1 else l2)
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
            acc[d, 2] += w * hcc
            dx0 = x0 - coords[c, i, 0]
            dx1 = x1 - coords[c, i, 1]
            acc[d, 3] += w * dx0
            acc[d, 4] += w * dx1
            acc[d, 5] += w * dx0 * dx0
            acc[d, 6] += w * dx0 * dx1
            acc[d, 7] += w * dx1 * dx1
            for j in range(k):
                wt = w * vals[p, j]
                acc[d, 8 + j] += wt
                acc[d, 8 + k + 2 * j] += wt * dx0
                acc[d, 9 + k + 2 * j] += wt * dx1


@njit(cache=True, error_model="numpy", inline="always")
def _linear_particle(x, cells, vals, p, origin, inv, hc):
    """Particle ``p``'s cell, position, barycentrics, cell size and values (1 or 2; else 0)."""
    c = cells[p]
    x0 = x[p, 0]
    x1 = x[p, 1]
    l0, l1, l2, _l3 = _bary_s(x0, x1, 0.0, c, origin, inv, 2)
    t1 = vals[p, 1] if vals.shape[1] == 2 else 0.0
    return c, x0, x1, l0, l1, l2, hc[c], vals[p, 0], t1


@njit(cache=True, error_model="numpy", inline="always")
def _node_moments(acc, d, w, dx0, dx1, hcc, t0, t1, two, o0):
    """Add one particle's linear moments to node ``d`` (:func:`_project_linear_tri`)."""
    if w < 0.0:
        w = 0.0
    elif w > 1.0:
        w = 1.0
    acc[d, 0] += w
    acc[d, 1] += 1.0
    acc[d, 2] += w * hcc
    acc[d, 3] += w * dx0
    acc[d, 4] += w * dx1
    acc[d, 5] += w * dx0 * dx0
    acc[d, 6] += w * dx0 * dx1
    acc[d, 7] += w * dx1 * dx1
    wt = w * t0
    acc[d, 8] += wt
    acc[d, o0] += wt * dx0
    acc[d, o0 + 1] += wt * dx1
    if two:
        wt = w * t1
        acc[d, 9] += wt
        acc[d, 12] += wt * dx0
        acc[d, 13] += wt * dx1


@njit(cache=True, error_model="numpy")
def _project_linear_tri(x, cells, vals, origin, inv, dofs, coords, hc, acc):
    """:func:`_project_accumulate_tri`'s linear moments of a field of 1 or 2 components.

    The same operations on every column in the same order (its results to the bit),
    the columns constants (:func:`_node_moments`, inlined): a quarter less time with
    Numba 0.56.
    """
    n = x.shape[0]
    two = vals.shape[1] == 2
    o0 = 10 if two else 9  # the column of W*T*dx of the first component
    for p in range(n):
        c, x0, x1, l0, l1, l2, hcc, t0, t1 = _linear_particle(x, cells, vals, p, origin, inv, hc)
        for i in range(3):
            w = l0 if i == 0 else (l1 if i == 1 else l2)
            dx0 = x0 - coords[c, i, 0]
            dx1 = x1 - coords[c, i, 1]
            _node_moments(acc, dofs[c, i], w, dx0, dx1, hcc, t0, t1, two, o0)
