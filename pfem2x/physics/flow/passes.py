r"""The two passes of a PFEM-2 flow step (``flow.extra_pass``), paper step 6.

A mixin of :class:`~pfem2x.physics.flow.pfem2.LagrangianFlow` (its attributes:
``cloud_``, ``u``, ``p``, ``force``, ``_u_old``, ``dt_last``, ``step_count``,
``_pass``, ``_move``).

Steps 1–3 run twice from the start-of-step particles; step 4, the particles' increment, in
the second pass only (the first pass's particles are dropped). The second pass solves the
:math:`\theta = 1/2` form of eq. 2.10 with the first pass's end-of-step mesh
velocity :math:`u^{(1)}` and source :math:`a^{(1)}` (the pressure
:math:`p^n + \delta p^{(1)}`) standing in for :math:`u^{n+1}`, :math:`a^{n+1}`:
along its path a particle sees the velocity and the source go linearly in time,
:math:`u(s) = (1 - s/\Delta t)\,u^n + (s/\Delta t)\,u^{(1)}` and the same for
:math:`a`. ``flow.pass_splits = 0`` (the default): in one move, each sub-step of the
move kernel with the velocity and source of its own ends' times
(:meth:`TwoPasses._move_linear`); :math:`m > 0`: :math:`m` equal parts of the move,
each with the blend frozen at its middle, one call of the move kernel each
(:math:`m = 1`: the streamline of :math:`\tfrac12(u^n + u^{(1)})` with the source
:math:`\tfrac12(a^n + a^{(1)})` for the whole step). The one move is the limit
:math:`m \to \infty` at the cost of about one part: Rayleigh–Taylor 100 × 400 at
Courant 8, largest tip difference to the Courant 0.5 run up to :math:`\tau = 2.5`,
0.0100 d against 0.0108 d with :math:`m = 4`, 5 % less CPU time per run.

``flow.predictor`` sets the first pass. ``"euler"`` (the paper's step 6): a
:math:`\theta = 0` pass along :math:`u^n` with the source :math:`a^n`.
``"extrapolated"``: a :math:`\theta = 1/2` pass like the second (its move in one
part: more measured no gain, the one linear move too) towards the estimate
:math:`u^n + \Delta t\,(u^n - u^{n-1})/\Delta t_{n-1}` (and the same for :math:`a`)
from the last step's change, so that the second pass starts from an end-of-step
estimate of second order instead of first; the first step, without a last step,
runs the :math:`\theta = 0` pass. Rayleigh–Taylor 100 × 400 at Courant 8, largest
tip difference to the Courant 0.5 run up to :math:`\tau = 2.5`: 0.029 d with
``"euler"`` and :math:`m = 1`, 0.013 d with ``"extrapolated"`` and :math:`m = 2`,
0.0096 d with :math:`m = 4` (17 % more CPU time than the first), all three with
backward Euler in the second pass; 0.0108 d with :math:`m = 4` and the SDIRK predictor
below, 0.0100 d with the defaults (docs/RESULTS.md, "Where PFEM-2's Δt error comes
from").

``flow.predictor_substeps = F`` (default 1) multiplies the first pass's sub-step limits
(``method.substep_courant``, ``method.substep_gradient``) by F; the second pass keeps
them. Rayleigh–Taylor 100 × 400 at Courant 8 with F = 2: 35 % fewer sub-steps in the
first pass, 12 % less CPU time per run, the tips within 0.0014 d of F = 1 (three
seeds), the largest difference to Courant 0.5 0.0101 d instead of 0.00996 d
(docs/BENCHMARKS.md, "Particles per cell, Courant number and seed").

``flow.predictor_particles = s`` (default 1) lets the first pass move only a share
:math:`s` of each cell's particles (at least one; :func:`_predictor_drop`): that move
only estimates the end of the step (:math:`u^{(1)}`, :math:`a^{(1)}`, the level set), and
the second pass moves every particle from the start of the step as before
(docs/BENCHMARKS.md, "The first pass's particles").

``flow.predictor_rtol`` and ``flow.predictor_divergence_rtol`` (default 0: the scene's
``flow.rtol`` and ``flow.divergence_rtol``) are the first pass's tolerances of its
viscous and pressure solves and of its discrete projection
(:meth:`TwoPasses._predictor_tolerances`); the second pass and the start of the step's
consistent pressure keep the scene's (docs/RESULTS.md, "The first pass's solves").

The second pass's viscous predictor (``flow.viscous_step = "sdirk2"``) is the two-stage
L-stable SDIRK method (:meth:`TwoPasses._viscous_sdirk2`), second order in
:math:`\Delta t`, instead of backward Euler, whose first-order decay the particles
keep step after step (FLIP increments): on the Taylor–Green vortex 32 × 32 at
Courant 8 the final velocity error is 0.0037 against 0.0081 with backward Euler
(Courant 0.5: 0.0028), 16 × 16 0.0068 against 0.0110 (Courant 0.5: 0.0134); the first
pass only estimates the end of the step and keeps backward Euler (SDIRK there too:
the same on Taylor–Green, Rayleigh–Taylor 50 × 200 0.001 d further from Courant 0.5).
Rayleigh–Taylor (:math:`\nu = 10^{-3}`) moves by at most 0.003 d.
Not with surface tension (the predictor's operator then has the capillary
term of :math:`\Delta t`): backward Euler (docs/RESULTS.md, "Where PFEM-2's Δt
error comes from").

The first pass's end source :math:`a^{(1)}` is built from its pressure
:math:`p^n + \delta p^{(1)}` (``flow.pass_pressure = "increment"``) or from the consistent
pressure of :math:`u^{(1)}` (``"consistent"``, solved like the start-of-step
:math:`p^n` of ``flow.explicit_pressure = "consistent"``: one more pressure solve per
step). :math:`\delta p` removes the divergence of :math:`u^*`; at a density ratio of
1000 its gradient on the light phase's nodes next to the interface is 85–180 g against
2–4 g for the consistent pressure of the same velocity, and as the second pass's source
it throws the air around (the dam break diverges in its 3rd step). The consistent
end source runs it, but costs the Taylor–Green vortex at Courant 8 (0.0139 against
0.0037): not the default (docs/RESULTS.md, "Why the incremental pressure diverges at
ratio 1000").

The blends, the extrapolation and the SDIRK predictor apply with the source integrated
along the path and the full source
(``flow.pressure_step = "increment"``, ``flow.light_source = "full"``); otherwise
the second pass is the streamline of :math:`\tfrac12(u^n + u^{(1)})` after an
Euler first pass, as in the paper.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from pfem2x import compat
from pfem2x import particles as P
from pfem2x.compat import MPI
from pfem2x.particles import _kernels as K

__all__ = ["SDIRK_GAMMA", "TwoPasses"]

#: the stage coefficient of the two-stage L-stable SDIRK method, 1 - 1/sqrt(2)
SDIRK_GAMMA = 1.0 - 0.5 * np.sqrt(2.0)


def _predictor_drop(cells: np.ndarray, n_cells: int, share: float) -> np.ndarray:
    r"""The particles the first pass leaves out (``flow.predictor_particles = share``).

    In each cell the particles in storage order keep ranks :math:`r` with
    :math:`r = 0` or :math:`\lfloor r s\rfloor > \lfloor (r - 1) s\rfloor`: the first
    and then about every :math:`1/s`-th, :math:`1 + \lfloor (n - 1) s\rfloor` of a cell's
    :math:`n` (:math:`\lceil n s\rceil` for :math:`s = 1/k`).
    Returns a boolean mask of the particles to drop.
    """
    return K.share_drop(cells, n_cells, float(share))


class TwoPasses:
    """``flow.extra_pass``: the first pass (``flow.predictor``) and the blended second pass."""

    cloud_: Any
    u: Any
    p: Any
    force: Any
    _u_old: Any
    #: the source a^n at the start of the last step (``flow.predictor = "extrapolated"``)
    _a_old: Any
    dt_last: float
    step_count: int
    pass_splits: int
    #: the viscous predictor of the current pass by the two-stage SDIRK (else backward Euler)
    _viscous_l_stable: bool = False
    #: the current move's sub-step limits over the scene's (flow.predictor_substeps)
    _substep_scale: float = 1.0
    #: flow.viscous_step = "sdirk2"
    viscous_sdirk: bool
    #: flow.pass_pressure = "consistent": the second pass's end source from the pressure
    #: solved from the first pass's velocity (:meth:`LagrangianFlow._consistent_pressure`)
    consistent_end_source: bool

    def _blends(self) -> bool:
        """Whether the passes blend the source in time (the full source along the path)."""
        return self.path_source and not self.gravity_only and not self.light_gravity_only

    def _two_passes(self, dt: float) -> None:
        """Steps 1–3 twice from the start-of-step particles, then 4 (see the module docstring)."""
        c = self.cloud_
        blends = self._blends()
        # the second pass's viscous predictor of second order (flow.viscous_step)
        sdirk = blends and self.viscous_sdirk and self.viscous and self.capillary is None
        with self.timer("particles"):
            share = float(self.scene.flow.predictor_particles)
            drop = _predictor_drop(c.cells, c.pmesh.n_cells, share) if share < 1.0 else None
            saved = c.save(drop)  # (the first pass's share stays in the cloud)
            guess = self._end_estimate(dt) if blends else None
            self._u_old.x.array[:] = self.u.x.array
            p_old = self.p.x.array.copy()
            force_old = self.force.x.array.copy()
            if self._a_old is not None:
                self._a_old.x.array[:] = force_old
        self._substep_scale = float(self.scene.flow.predictor_substeps)
        self._first_pass = True
        self._predictor_tolerances(True)
        try:
            if guess is None:
                self._pass(dt, 0.0)
            else:
                self.u.x.array[:] = guess[0]
                self._pass(dt, 0.5, (force_old, guess[1], 1))
        finally:
            self._substep_scale, self._first_pass = 1.0, False
            self._predictor_tolerances(False)
        if self.consistent_end_source:
            self._consistent_pressure()  # a^(1) from the pressure of u^(1)
        self._viscous_l_stable = sdirk
        # second pass from the start-of-step state, theta = 1/2 in eq. 2.10
        with self.timer("particles"):
            c.restore(saved)
            self.p.x.array[:] = p_old
        try:
            if blends:
                self._pass(dt, 0.5, (force_old, self.force.x.array.copy(), self.pass_splits))
            else:
                self.force.x.array[:] = 0.5 * (self.force.x.array + force_old)
                self._pass(dt, 0.5)
        finally:
            self._viscous_l_stable = False

    def _predictor_tolerances(self, first: bool) -> None:
        """The pressure step's solve tolerances of the first pass (``first``) or the scene's.

        ``flow.predictor_rtol`` (the viscous and pressure solves) and
        ``flow.predictor_divergence_rtol`` (the discrete projection), where > 0.
        """
        fl, proj = self.scene.flow, self.projection
        rtol, div_rtol = float(fl.predictor_rtol), float(fl.predictor_divergence_rtol)
        proj.pass_rtol = rtol if first and rtol > 0.0 else None
        proj.pass_divergence_rtol = div_rtol if first and div_rtol > 0.0 else None

    def _viscous_sdirk2(self, dt: float) -> None:
        r"""The viscous predictor of a :math:`\theta = 1/2` pass: two-stage L-stable SDIRK.

        :math:`M_\rho\dot u = -K_\mu u` from :math:`\hat u` over :math:`\Delta t` by the
        stiffly accurate two-stage SDIRK method (R. Alexander, SIAM J. Numer. Anal. 14
        (1977) 1006–1021), :math:`\gamma = 1 - 1/\sqrt2`: stage 1
        :math:`M_\rho(u_1 - \hat u)/(\gamma\Delta t) + K_\mu u_1 = 0`, stage 2
        :math:`M_\rho(u^* - r)/(\gamma\Delta t) + K_\mu u^* = 0` with
        :math:`r = (1 - c)\,\hat u + c\,u_1`, :math:`c = (1 - \gamma)/\gamma`: the
        operator :math:`M_\rho/(\gamma\Delta t) + K_\mu` of :meth:`_viscous_operator`
        (called with :math:`\gamma\Delta t`) solved twice. Second order in
        :math:`\Delta t` (backward Euler: first), and the stiff modes are damped: the
        amplification factor :math:`R(z) = w(1 - c + c\,w)`, :math:`w = 1/(1 + \gamma z)`,
        :math:`z = \lambda\Delta t`, stays within :math:`|R| \le 0.21` for large
        :math:`z` and goes to 0 (Crank–Nicolson: :math:`R \to -1`).

        Parameters
        ----------
        dt
            The step (the operator is already that of :math:`\gamma\,dt`).
        """
        g = SDIRK_GAMMA
        proj = self.projection
        with self.timer("solve"):
            self.u_star.x.array[:] = self.u_hat.x.array  # the start: no viscous change
            it = self.m_solver.solve(self.b_m, compat.petsc_vec(self.u_star), guess=True)
            self.u_star.x.scatter_forward()
        n = len(self.b_m.array_r)
        c = (1.0 - g) / g
        r2 = (1.0 - c) * self.u_hat.x.array[:n] + c * self.u_star.x.array[:n]
        self.b_m.array[:] = self._diag.array_r * r2
        self._set_viscous_bc()
        with self.timer("solve"):
            it += self.m_solver.solve(self.b_m, compat.petsc_vec(self.u_star), guess=True)
            self.u_star.x.scatter_forward()
        proj.iterations["momentum"] = it

    def _end_estimate(self, dt: float) -> tuple[np.ndarray, np.ndarray] | None:
        """``flow.predictor = "extrapolated"``: ``u^n + dt du/dt`` and ``a^n + dt da/dt``.

        The rates are the last step's changes of the mesh velocity (``_u_old``: the
        last step's :math:`u^n`) and of the source (``_a_old``); ``None`` without a
        last step (the first step, ``"euler"``).
        """
        if self._a_old is None or self.step_count == 0 or not self.dt_last > 0.0:
            return None
        r = dt / self.dt_last
        u, a = self.u.x.array, self.force.x.array
        return u + r * (u - self._u_old.x.array), a + r * (a - self._a_old.x.array)

    def _blended_move(self, dt: float, a0: np.ndarray, a1: np.ndarray, m: int) -> None:
        r"""Step 1 of a blended pass: ``m`` moves, each with the velocity and source of its middle.

        ``m = 0``: one move with both linear in time (:meth:`_move_linear`).

        Part :math:`j` of :math:`m` moves over :math:`\Delta t/m` along the streamline of
        :math:`(1-\tau_j)\,u^n + \tau_j\,u^{(1)}` (``_u_old``, ``u``) with the source
        :math:`(1-\tau_j)\,a_0 + \tau_j\,a_1` integrated on the path,
        :math:`\tau_j = (j + 1/2)/m`. :math:`m = 1`: their means over the step.
        """
        if m == 0:
            self._move_linear(dt, a0, a1)
            return
        if m == 1:
            self.force.x.array[:] = 0.5 * (a1 + a0)
            self._move(dt, 0.5)
            return
        substeps = 0
        for j in range(m):
            tau = (j + 0.5) / m
            self.force.x.array[:] = (1.0 - tau) * a0 + tau * a1
            self._move(dt / m, tau)
            substeps += self.path_substeps
        self.path_substeps = substeps

    def _move_linear(self, dt: float, a0: np.ndarray, a1: np.ndarray) -> None:
        r"""Step 1 of a blended pass in one move: velocity and source linear in time.

        At time :math:`s` of the step a particle sees
        :math:`(1 - s/\Delta t)\,u^n + (s/\Delta t)\,u^{(1)}` (``_u_old``, ``u``) and the
        same blend of ``a0``, ``a1``; each sub-step of the move takes the values at its own
        ends' times (the limit :math:`m \to \infty` of :meth:`_blended_move`).
        """
        gd = self.gdim
        meth = self.scene.method
        stats = P.advect(
            self.cloud_,
            self._u_old.x.array.reshape(-1, gd),
            dt,
            courant=meth.substep_courant,
            gradient_courant=meth.substep_gradient,
            source=a0.reshape(-1, gd),
            source_field="u",
            velocity_end=self.u.x.array.reshape(-1, gd),
            source_end=a1.reshape(-1, gd),
        )
        self._count_substeps(stats)

    def _count_substeps(self, stats: Any) -> None:
        """``path_substeps``: the move's sub-steps per particle, over all ranks (collective)."""
        n = float(self.comm.allreduce(float(self.cloud_.n), op=MPI.SUM))
        steps = float(self.comm.allreduce(float(stats.substeps), op=MPI.SUM))
        self.path_substeps = max(1, round(steps / max(n, 1.0)))
