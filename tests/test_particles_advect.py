"""Moving particles: X-IVAS sub-stepping, walls, periodic wrap, outflow/inflow, sources."""

import numpy as np
import pytest

from pfem2x import compat
from pfem2x.compat import MPI, dolfinx
from pfem2x.mesh import build_mesh
from pfem2x.particles import Cloud, advect, assign_ids, seed_cells, seed_inflow


def _rotation(d):
    V = compat.function_space(d.mesh, 1, (2,))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.stack([-x[1], x[0]]))
    return u


@pytest.mark.mpi
@pytest.mark.parametrize("callable_velocity", [False, True])
def test_rigid_rotation_returns_home(comm, callable_velocity):
    """One revolution in 8 steps (step Courant ~5 at r = 0.8, h = 0.14).

    Measured max return error 0.0040 (P1) / 0.0073 (callable) with the
    default sub-step limits (Courant 0.5, gradient Courant 0.1); tolerance 0.01.
    """
    d = build_mesh(comm, "rectangle", [[-1.0, -1.0], [1.0, 1.0]], [20, 20])
    cl = Cloud(d, {"x0": (2,)})
    seed_cells(cl, 4, seed=3, region=lambda x: np.linalg.norm(x, axis=1) < 0.8)
    cl["x0"] = cl.x
    n0 = cl.global_count()
    u = _rotation(d)
    vel = (lambda x, t: np.stack([-x[:, 1], x[:, 0]], axis=1)) if callable_velocity else u
    dt = 2 * np.pi / 8
    step_courant = 0.8 * dt / d.min_h()
    assert step_courant > 5.0
    for i in range(8):
        advect(cl, vel, dt, t=i * dt)
    assert cl.global_count() == n0
    assert cl.check()
    err = np.linalg.norm(cl.x - cl["x0"], axis=1)
    emax = comm.allreduce(err.max() if cl.n else 0.0, op=MPI.MAX)
    assert emax < 0.01


def test_fixed_substeps_and_theta(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [4.0, 1.0]], [16, 4])
    cl = Cloud(d, {"x0": (2,)})
    seed_cells(cl, 4, seed=1, region=lambda x: x[:, 0] < 1.0)
    cl["x0"] = cl.x
    V = compat.function_space(d.mesh, 1, (2,))
    un = dolfinx.fem.Function(V)
    un.interpolate(lambda x: np.stack([np.ones(x.shape[1]), np.zeros(x.shape[1])]))
    un1 = dolfinx.fem.Function(V)
    un1.interpolate(lambda x: np.stack([2.0 * np.ones(x.shape[1]), np.zeros(x.shape[1])]))
    st = advect(cl, un, 1.0, velocity_next=un1, theta=0.5, substeps=7)
    # eq. (2.10) with uniform fields: dx = (1-theta)*1*dt + theta*2*dt = 1.5
    assert np.allclose(cl.x[:, 0] - cl["x0"][:, 0], 1.5, atol=1e-12)
    assert np.allclose(cl.x[:, 1], cl["x0"][:, 1], atol=1e-12)
    assert st.substeps == 7 * cl.n
    assert cl.check()


@pytest.mark.mpi
@pytest.mark.parametrize("callable_velocity", [False, True])
def test_periodic_interval_wraps(comm, callable_velocity):
    d = build_mesh(comm, "interval", [0.0, 1.0], [20], periodic=[True])
    cl = Cloud(d, {"x0": ()})
    seed_cells(cl, 3, seed=4)
    cl["x0"] = cl.x[:, 0]
    n0 = cl.global_count()
    V = compat.function_space(d.mesh, 1, (1,))
    u = dolfinx.fem.Function(V)
    u.x.array[:] = 0.7
    vel = (lambda x, t: np.full((len(x), 1), 0.7)) if callable_velocity else u
    dt = 0.9  # 12.6 cells per step
    for _ in range(4):
        advect(cl, vel, dt)
    assert cl.global_count() == n0
    assert cl.check()
    expect = np.mod(cl["x0"] + 0.7 * dt * 4, 1.0)
    diff = np.abs(cl.x[:, 0] - expect)
    diff = np.minimum(diff, 1.0 - diff)
    assert diff.max(initial=0.0) < 1e-10


@pytest.mark.mpi
def test_periodic_channel_2d(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [2.0, 1.0]], [8, 4], periodic=[True, False])
    cl = Cloud(d, {"x0": (2,)})
    seed_cells(cl, 6, seed=8)
    cl["x0"] = cl.x
    n0 = cl.global_count()
    vel = lambda x, t: np.stack([np.full(len(x), 1.3), 0.2 * np.sin(np.pi * x[:, 1])], axis=1)  # noqa: E731
    for _ in range(3):
        advect(cl, vel, 1.0)
    assert cl.global_count() == n0 and cl.check()


@pytest.mark.mpi
def test_closed_box_keeps_particles(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [10, 10])
    cl = Cloud(d, {})
    seed_cells(cl, 6, seed=2)
    n0 = cl.global_count()
    V = compat.function_space(d.mesh, 1, (2,))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.stack([1.0 + 0 * x[0], 0.4 + 0 * x[0]]))
    for _ in range(5):
        advect(cl, u, 0.5)  # Courant ~4 into the walls
    assert cl.global_count() == n0
    assert cl.check()
    assert np.all((cl.x >= -1e-12) & (cl.x <= 1 + 1e-12))
    # everything slid into the top-right corner region
    assert cl.x[:, 0].min(initial=1.0) > 1.0 - 1e-6


@pytest.mark.mpi
def test_outflow_deletes_and_counts(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [2.0, 1.0]], [8, 4])
    cl = Cloud(d, {"id": ()}, outflow=lambda x: x[:, 0] > 2.0 - 1e-9)
    seed_cells(cl, 5, seed=6)
    assign_ids(cl)
    n0 = cl.global_count()
    expect_out = comm.allreduce(int((cl.x[:, 0] + 0.75 > 2.0).sum()), op=MPI.SUM)
    vel = lambda x, t: np.stack([np.full(len(x), 1.0), np.zeros(len(x))], axis=1)  # noqa: E731
    st = advect(cl, vel, 0.75)
    out = comm.allreduce(st.outflow, op=MPI.SUM)
    assert out == expect_out > 0
    assert cl.global_count() == n0 - out


def test_inflow_hook_refills(comm):
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [2.0, 1.0]], [8, 4])
    cl = Cloud(
        d,
        {"T": ()},
        outflow=lambda x: x[:, 0] > 2.0 - 1e-9,
        inflow=lambda x: x[:, 0] < 1e-9,
    )
    seed_cells(cl, 5, seed=6)
    cl["T"] = 0.0
    vel = lambda x, t: np.stack([np.full(len(x), 1.0), np.zeros(len(x))], axis=1)  # noqa: E731
    advect(cl, vel, 0.6)
    pm = cl.pmesh
    inflow_cells = pm.inflow_facets[: pm.n_owned].any(axis=1)
    assert inflow_cells.any()
    assert np.all(cl.counts_per_cell()[inflow_cells] == 0)
    added = seed_inflow(cl, 5, {"T": lambda x: 1.0 + x[:, 1]}, seed=1)
    assert added == 5 * inflow_cells.sum()
    assert np.all(cl.counts_per_cell()[inflow_cells] == 5)
    new = cl.cells  # new particles sit in inflow cells with the inflow value
    m = inflow_cells[new]
    assert np.allclose(cl["T"][m], 1.0 + cl.x[m, 1])
    assert cl.check()


@pytest.mark.mpi
@pytest.mark.parametrize("nodal", [False, True])
def test_source_integrated_along_path(comm, nodal):
    """q = x (P1, exact) or q(x, t) = x + t along u = (1, 0): trapezoid is exact."""
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [4.0, 1.0]], [16, 4])
    cl = Cloud(d, {"T": (), "x0": (2,)})
    seed_cells(cl, 4, seed=7, region=lambda x: x[:, 0] < 1.0)
    cl["x0"] = cl.x
    V = compat.function_space(d.mesh, 1, (2,))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.stack([np.ones(x.shape[1]), np.zeros(x.shape[1])]))
    dt, t0 = 2.0, 0.5
    if nodal:
        Q = dolfinx.fem.Function(compat.function_space(d.mesh, 1))
        Q.interpolate(lambda x: x[0])
        advect(cl, u, dt, t=t0, source=Q, source_field="T")
        expect = cl["x0"][:, 0] * dt + dt**2 / 2
    else:
        advect(cl, u, dt, t=t0, source=lambda x, t: x[:, 0] + t, source_field="T")
        expect = cl["x0"][:, 0] * dt + dt**2 / 2 + (t0 + dt) ** 2 / 2 - t0**2 / 2
    assert np.allclose(cl["T"], expect, atol=1e-10)
    assert np.allclose(cl.x[:, 0], cl["x0"][:, 0] + dt, atol=1e-12)


@pytest.mark.mpi
@pytest.mark.parametrize("callable_velocity", [False, True])
def test_vector_source_per_component(comm, callable_velocity):
    """A vector P1 source (k = 2) along u = (1, 0): each component exact, as its scalar source."""
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [4.0, 1.0]], [16, 4])
    clouds = []
    for _ in range(2):
        cl = Cloud(d, {"F": (2,), "T": (), "x0": (2,)})
        seed_cells(cl, 4, seed=7, region=lambda x: x[:, 0] < 1.0)
        cl["x0"] = cl.x
        clouds.append(cl)
    V = compat.function_space(d.mesh, 1, (2,))
    u = dolfinx.fem.Function(V)
    u.interpolate(lambda x: np.stack([np.ones(x.shape[1]), np.zeros(x.shape[1])]))
    vel = (lambda x, t: np.tile([1.0, 0.0], (len(x), 1))) if callable_velocity else u
    F = dolfinx.fem.Function(V)
    F.interpolate(lambda x: np.stack([x[0], 2.0 - 0.5 * x[0] + x[1]]))
    Q = dolfinx.fem.Function(compat.function_space(d.mesh, 1))
    Q.interpolate(lambda x: 2.0 - 0.5 * x[0] + x[1])
    dt = 2.0
    advect(clouds[0], vel, dt, source=F, source_field="F", source_scale=3.0)
    advect(clouds[1], vel, dt, source=Q, source_field="T", source_scale=3.0)
    x0 = clouds[0]["x0"]
    expect = np.stack(
        [x0[:, 0] * dt + dt**2 / 2, (2.0 - 0.5 * x0[:, 0] + x0[:, 1]) * dt - dt**2 / 4]
    )
    assert np.allclose(clouds[0]["F"], 3.0 * expect.T, atol=1e-10)
    assert np.array_equal(clouds[0].x, clouds[1].x)
    assert np.array_equal(clouds[0]["F"][:, 1], clouds[1]["T"])  # bit-identical per component
    with pytest.raises(ValueError, match="source_field 'T'"):
        advect(clouds[0], vel, dt, source=F, source_field="T")


def _uniform(V, vx, vy=0.0):
    f = dolfinx.fem.Function(V)
    f.interpolate(lambda x: np.stack([np.full(x.shape[1], vx), np.full(x.shape[1], vy)]))
    return f


@pytest.mark.mpi
def test_velocity_and_source_linear_in_time(comm):
    """``velocity_end`` / ``source_end``: uniform fields linear in time are integrated exactly.

    u goes from (1, 0) to (3, 1) over dt = 1 and the source from (2, 0) to (0, 4):
    every particle moves by dt (u0 + u1) / 2 = (2, 0.5) and gains dt (a0 + a1) / 2
    = (1, 2), whatever its sub-steps (Heun and the trapezoid are exact for a
    linear function of time).
    """
    d = build_mesh(comm, "rectangle", [[0.0, 0.0], [6.0, 3.0]], [24, 12])
    cl = Cloud(d, {"u": (2,), "x0": (2,)})
    seed_cells(cl, 4, seed=2, region=lambda x: (x[:, 0] < 2.0) & (x[:, 1] < 1.5))
    cl["x0"] = cl.x
    V = compat.function_space(d.mesh, 1, (2,))
    u0, u1, a0, a1 = _uniform(V, 1.0), _uniform(V, 3.0, 1.0), _uniform(V, 2.0), _uniform(V, 0, 4)
    st = advect(cl, u0, 1.0, source=a0, source_field="u", velocity_end=u1, source_end=a1)
    assert st.substeps > cl.global_count()  # the Courant limit splits the path
    assert np.allclose(cl.x - cl["x0"], [2.0, 0.5], atol=1e-12)
    assert np.allclose(cl["u"], [1.0, 2.0], atol=1e-12)
    with pytest.raises(ValueError, match="theta = 0"):
        advect(cl, u0, 1.0, velocity_next=u1, theta=0.5, velocity_end=u1)
    with pytest.raises(ValueError, match="source_end needs source"):
        advect(cl, u0, 1.0, velocity_end=u1, source_end=a1)


def test_linear_in_time_is_the_limit_of_frozen_parts():
    """Moves in ``m`` parts, each with the velocity and source frozen at its middle time,
    approach the one move linear in time as ``m`` grows (a rotating, varying field);
    reference: the linear-in-time move in 400 fixed sub-steps. The one move at the
    default sub-step limits is closer to it than four frozen parts."""
    d = build_mesh(MPI.COMM_SELF, "rectangle", [[-1.0, -1.0], [1.0, 1.0]], [24, 24])
    V = compat.function_space(d.mesh, 1, (2,))
    u0, u1, a0, a1 = (dolfinx.fem.Function(V) for _ in range(4))
    u0.interpolate(lambda x: np.stack([-x[1], x[0]]))
    u1.interpolate(lambda x: np.stack([-x[1] + 0.5 * x[0], x[0] + 0.3]))
    a0.interpolate(lambda x: np.stack([x[0] * x[1], np.cos(x[0])]))
    a1.interpolate(lambda x: np.stack([x[1], np.sin(2 * x[1])]))
    arr = [np.asarray(f.x.array).reshape(-1, 2) for f in (u0, u1, a0, a1)]
    dt = 1.0

    def cloud():
        cl = Cloud(d, {"u": (2,)})
        seed_cells(cl, 3, seed=4, region=lambda x: np.linalg.norm(x, axis=1) < 0.5)
        assign_ids(cl)
        return cl

    def err(cl, ref):
        o1, o2 = np.argsort(cl["id"]), np.argsort(ref["id"])
        return max(np.abs(cl.x[o1] - ref.x[o2]).max(), np.abs(cl["u"][o1] - ref["u"][o2]).max())

    kw = {"source_field": "u", "velocity_end": u1, "source_end": a1}
    ref = cloud()
    advect(ref, u0, dt, source=a0, substeps=400, **kw)
    one = cloud()
    advect(one, u0, dt, source=a0, **kw)
    errs = []
    for m in (1, 4, 16):
        cl = cloud()
        for j in range(m):
            tau = (j + 0.5) / m
            vel = (1 - tau) * arr[0] + tau * arr[1]
            src = (1 - tau) * arr[2] + tau * arr[3]
            advect(cl, vel, dt / m, source=src, source_field="u")
        errs.append(err(cl, ref))
    # measured 0.082, 0.0048, 0.00046 (m = 1, 4, 16); the one move 0.0013
    assert errs[0] > 0.05 and errs[1] < errs[0] / 10 and errs[2] < errs[1] / 5
    assert err(one, ref) < errs[1] / 2  # closer than 4 frozen parts, at the default limits


@pytest.mark.mpi
def test_theta_stage_without_contraction_terminates(comm):
    """Eq. (2.10) with theta*dt*|grad V| = 3: plain fixed-point iteration diverges.

    V^{n+1}(x) = -3 (x - c) around the domain centre, V^n = 0, theta = dt = 1:
    the exact answer is x = (x0 + 3 c) / 4. Undamped iterates oscillate with
    growing amplitude; under MPI they crossed the partition boundary and the
    particles were handed back and forth between the ranks for ever (seen as a
    hang of 2-rank Rayleigh-Taylor runs). Damped iteration converges.
    """
    import signal

    def _hang(*_):
        raise TimeoutError("advect did not return: particles passed between ranks for ever")

    old = signal.signal(signal.SIGALRM, _hang)
    signal.alarm(120)
    try:
        d = build_mesh(comm, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [16, 16])
        cl = Cloud(d, {"x0": (2,)})
        seed_cells(cl, 6, seed=5)
        cl["x0"] = cl.x
        n0 = cl.global_count()
        V = compat.function_space(d.mesh, 1, (2,))
        un = dolfinx.fem.Function(V)
        un1 = dolfinx.fem.Function(V)
        un1.interpolate(lambda x: np.stack([-3.0 * (x[0] - 0.5), -3.0 * (x[1] - 0.5)]))
        advect(cl, un, 1.0, velocity_next=un1, theta=1.0, substeps=1)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)
    assert cl.global_count() == n0
    assert cl.check()
    exact = (cl["x0"] + 3.0 * 0.5) / 4.0
    err = np.abs(cl.x - exact).max() if cl.n else 0.0
    assert comm.allreduce(err, op=MPI.MAX) < 1e-9


@pytest.mark.parametrize("mode", ["courant", "fixed", "theta", "blend", "blend-sparse"])
def test_triangle_fast_path_equals_generic_loop(mode):
    """The 2D move (its regular sub-steps' loop, then the per-particle loop) is the generic loop.

    Same state, velocities and source through :func:`_advect_p1_tri` and
    :func:`_advect_p1_any`: positions, cells, displacements, source integrals
    and sub-step counts equal to the last bit (walls, periodic wrap, the
    theta stage, velocity and source linear in time and particles stopping
    at an outflow included). The 2D loop takes the gradient's sub-step rate
    from a per-cell table when there are at least as many particles as cells
    (``blend``) and per sub-step otherwise (``blend-sparse``).
    """
    from pfem2x.particles import _kernels as K  # noqa: PLC0415

    d = build_mesh(
        MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [2.0, 1.0]], [20, 10], periodic=[True, False]
    )
    cl = Cloud(d, {"T": ()}, outflow=lambda x: (x[:, 1] > 1.0 - 1e-9) & (x[:, 0] > 1.5))
    sparse = mode == "blend-sparse"
    seed_cells(cl, 6, seed=5, region=(lambda x: x[:, 0] > 1.8) if sparse else None)
    V = compat.function_space(d.mesh, 1, (2,))
    u, u1, f = (dolfinx.fem.Function(V) for _ in range(3))
    u.interpolate(lambda x: np.stack([1.5 + np.sin(3 * x[1]), 0.8 * np.cos(2 * np.pi * x[0])]))
    u1.interpolate(lambda x: np.stack([1.0 + x[1], 0.5 * np.sin(2 * np.pi * x[0])]))
    f.interpolate(lambda x: np.stack([np.cos(x[0]), x[0] * x[1]]))
    M = cl.pmesh.arrays
    un, un1, q = (np.asarray(g.x.array).reshape(-1, 2).copy() for g in (u, u1, f))
    dt, theta = 0.4, (0.5 if mode == "theta" else 0.0)
    nsub = 9 if mode == "fixed" else 0
    blend = mode.startswith("blend")
    du, dq = (un1 - un, 0.3 * q[:, ::-1].copy()) if blend else (np.zeros((1, 1)),) * 2
    table = K._gradient_rates(un, du, M.dofs, M.inv, 0.1, blend, nsub, cl.n)
    assert len(table) == (0 if sparse or nsub else len(M.dofs))
    results = []
    for kern in (K._advect_p1_tri, K._advect_p1_any):
        n = cl.n
        x, cell = cl.x.copy(), cl.cells.copy()
        t_left, stage = np.full(n, dt), np.zeros(n)
        aux, acc, status = np.zeros((n, 2)), np.zeros((n, 2)), np.zeros(n, dtype=np.int8)
        tables = [K.affine_p1(a, M.dofs, M.inv) for a in (un, du, q, dq)]
        steps = kern(
            x, cell, t_left, aux, acc, stage, status, dt, un, un1, theta, True, 0.5, 0.1,
            nsub, M.origin, M.inv, M.nbr, M.pshift, M.period, M.h, M.dofs, M.n_owned, du,
            blend, *tables,
        )  # fmt: skip
        results.append((steps, x, cell, t_left, aux, acc, stage, status))
    (s1, *a1), (s2, *a2) = results
    assert s1 == s2 > cl.n
    assert (a1[-1] == K.ST_OUTFLOW).any()  # some particles leave on the way
    for v1, v2 in zip(a1, a2, strict=True):
        assert np.array_equal(v1, v2)


@pytest.mark.parametrize(
    "kind,bounds,cells",
    [
        ("interval", [[0.0], [2.0]], [7]),
        ("rectangle", [[0.0, 0.0], [2.0, 1.0]], [6, 5]),
        ("box", [[0.0, 0.0, 0.0], [1.0, 1.0, 2.0]], [3, 3, 4]),
    ],
)
def test_affine_table_is_the_p1_field(kind, bounds, cells):
    """The move's per-cell affine form of a P1 field gives the barycentric P1 value.

    Each component at random points of every cell, from :func:`affine_p1` and
    :func:`_eval_a` against :func:`evaluate_p1`, to round-off.
    """
    from pfem2x.particles import _kernels as K  # noqa: PLC0415

    d = build_mesh(MPI.COMM_SELF, kind, bounds, cells)
    cl = Cloud(d, {})
    seed_cells(cl, 4, seed=3)
    M = cl.pmesh.arrays
    gdim = M.origin.shape[1]
    rng = np.random.default_rng(7)
    vals = rng.standard_normal((cl.pmesh.n_dofs, 3))
    table = K.affine_p1(vals, M.dofs, M.inv)
    assert table.shape == (len(M.dofs), 3, gdim + 1)
    ref = K.evaluate_p1(cl.x, cl.cells, vals, M)
    got = np.empty_like(ref)
    x = np.zeros((cl.n, 3))
    x[:, :gdim] = cl.x
    for p in range(cl.n):
        for j in range(3):
            got[p, j] = K._eval_a(table, j, cl.cells[p], *x[p], M.origin, gdim)
    assert np.abs(got - ref).max() < 1e-12 * np.abs(vals).max() * max(cells)


def test_affine_table_of_triangles_written_out_to_the_bit():
    """The triangles' table (loops over the axes written out) holds the bits of the generic
    loop's sums from 0.0, signed zeros included."""
    from pfem2x.particles import _kernels as K  # noqa: PLC0415

    d = build_mesh(MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [1.0, 2.0]], [7, 9])
    M = Cloud(d, {}).pmesh.arrays
    rng = np.random.default_rng(8)
    vals = rng.standard_normal((len(M.dofs) + 20, 2))
    vals[::5] = -0.0
    vals[1::5] = 0.0
    table = K.affine_p1(vals, M.dofs, M.inv)
    v = vals[M.dofs]  # (cells, 3, k)
    e1, e2 = v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]
    want = np.empty_like(table)
    want[:, :, 0] = v[:, 0]
    for b in range(2):
        want[:, :, 1 + b] = (0.0 + e1 * M.inv[:, 0, b, None]) + e2 * M.inv[:, 1, b, None]
    assert np.array_equal(table.view(np.int64), want.view(np.int64))
