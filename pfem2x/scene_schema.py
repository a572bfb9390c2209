"""The scene schema: key checkers and the table of allowed keys.

Every ``[section].key`` of a scene is a :class:`Key` in :data:`SCHEMA` (checker,
default, doc line), with :data:`pfem2x.scene_readers.FRAME_KEYS` telling which frame
reads which numerical switch. :mod:`pfem2x.scene` validates scenes against it;
:mod:`pfem2x.scene_reference` renders it as docs/SCENES.md.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["SCHEMA", "Key", "SceneError", "scene_name"]


#: Refuse scenes whose particle cloud alone would need more than this (bytes).
MAX_PARTICLE_BYTES = 8 * 1024**3
#: Refuse meshes with more cells than this (before allocating).
MAX_CELLS = 20_000_000
#: Estimated bytes per particle (positions, cell, fields, work arrays).
BYTES_PER_PARTICLE = 160


class SceneError(ValueError):
    """A scene or CLI input is invalid; the message names the key or file."""


# --------------------------------------------------------------------------
# Schema
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Key:
    """One allowed key: a type checker, a default and a doc line."""

    check: Callable[[str, Any], Any]
    default: Any = None
    required: bool = False
    doc: str = ""


def _type_name(v: Any) -> str:
    return {
        bool: "a boolean",
        int: "an integer",
        float: "a number",
        str: "a string",
        list: "a list",
        dict: "a table",
    }.get(type(v), type(v).__name__)


def number(
    lo: float | None = None, hi: float | None = None, lo_open: bool = False
) -> Callable[[str, Any], float]:
    """A real number, optionally within ``[lo, hi]`` (``(lo, hi]`` if ``lo_open``)."""

    def check(key: str, v: Any) -> float:
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise SceneError(f"{key}: expected a number, got {_type_name(v)} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise SceneError(f"{key}: must be finite, got {v}")
        if lo is not None and (v < lo or (lo_open and v <= lo)):
            raise SceneError(f"{key}: must be {'>' if lo_open else '>='} {lo:g}, got {v:g}")
        if hi is not None and v > hi:
            raise SceneError(f"{key}: must be <= {hi:g}, got {v:g}")
        return v

    return check


def auto_or(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    """``"auto"`` (the run chooses; see the key's doc) or what ``check`` accepts."""

    def either(key: str, v: Any) -> Any:
        if v == "auto":
            return v
        try:
            return check(key, v)
        except SceneError as exc:
            raise SceneError(f'{exc} (or "auto")') from None

    return either


def integer(lo: int | None = None, hi: int | None = None) -> Callable[[str, Any], int]:
    """An integer, optionally within ``[lo, hi]``."""

    def check(key: str, v: Any) -> int:
        if isinstance(v, bool) or not isinstance(v, int):
            if isinstance(v, float) and v.is_integer():
                v = int(v)
            else:
                raise SceneError(f"{key}: expected an integer, got {_type_name(v)} {v!r}")
        if lo is not None and v < lo:
            raise SceneError(f"{key}: must be >= {lo}, got {v}")
        if hi is not None and v > hi:
            raise SceneError(f"{key}: must be <= {hi}, got {v}")
        return int(v)

    return check


def boolean(key: str, v: Any) -> bool:
    """A boolean."""
    if not isinstance(v, bool):
        raise SceneError(f"{key}: expected true or false, got {_type_name(v)} {v!r}")
    return v


def string(key: str, v: Any) -> str:
    """A string."""
    if not isinstance(v, str):
        raise SceneError(f"{key}: expected a string, got {_type_name(v)} {v!r}")
    return v


def choice(*options: str) -> Callable[[str, Any], str]:
    """One of ``options``."""

    def check(key: str, v: Any) -> str:
        string(key, v)
        if v not in options:
            near = difflib.get_close_matches(v, options, n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            raise SceneError(f"{key}: {v!r} is not one of {', '.join(options)}{hint}")
        return v

    return check


#: The built-in case diagnostics ``scene.case`` can name: the keys of
#: :data:`pfem2x.cases._CASES` and ``manufactured-1d`` (a test keeps them equal),
#: listed here so that validating a scene does not import the diagnostics.
CASES = (
    "dam-break",
    "gaussian-hill",
    "manufactured-1d",  # no diagnostics beyond the exact-solution error (not in _CASES)
    "rayleigh-taylor",
    "rising-bubble",
    "static-drop",
    "zalesak",
)


def case_name(key: str, v: Any) -> str:
    """``""`` (no case diagnostics) or one of :data:`CASES`."""
    string(key, v)
    if v and v not in CASES:
        near = difflib.get_close_matches(v, CASES, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise SceneError(
            f'{key}: {v!r} is not a built-in case{hint}; known: {", ".join(CASES)} (or "" for none)'
        )
    return v


def expr_text(key: str, v: Any) -> str | float:
    """An expression string or a number (compiled later, once params are known)."""
    if isinstance(v, bool) or not isinstance(v, str | int | float):
        raise SceneError(
            f"{key}: expected an expression string or a number, got {_type_name(v)} {v!r}"
        )
    return v


def list_of(
    item: Callable[[str, Any], Any], min_len: int = 1, max_len: int = 3
) -> Callable[[str, Any], list]:
    """A list of ``min_len..max_len`` items each checked by ``item``."""

    def check(key: str, v: Any) -> list:
        if not isinstance(v, list):
            raise SceneError(f"{key}: expected a list, got {_type_name(v)} {v!r}")
        if not (min_len <= len(v) <= max_len):
            raise SceneError(f"{key}: expected {min_len}..{max_len} entries, got {len(v)}")
        return [item(f"{key}[{i}]", x) for i, x in enumerate(v)]

    return check


def partition_check(key: str, v: Any) -> str | list[int]:
    """``"rows"``, ``"columns"`` or a ``[px, py]`` grid."""
    if isinstance(v, str):
        return choice("rows", "columns")(key, v)
    if not isinstance(v, list):
        raise SceneError(f'{key}: expected "rows", "columns" or [px, py], got {v!r}')
    return list_of(integer(1, 100_000), 2, 2)(key, v)


#: The smallest extent of ``mesh.bounds`` in any direction (DOLFINx refuses a box whose
#: width is below the double precision epsilon).
_MIN_EXTENT = 2.3e-16


def bounds_check(key: str, v: Any) -> list[list[float]]:
    """``[lo, hi]`` corners: numbers (interval) or equal-length lists of numbers."""
    if not isinstance(v, list) or len(v) != 2:
        raise SceneError(f"{key}: expected [lo, hi], got {v!r}")
    out = []
    for i, c in enumerate(v):
        c = c if isinstance(c, list) else [c]
        out.append(list_of(number(), 1, 3)(f"{key}[{i}]", c))
    if len(out[0]) != len(out[1]):
        raise SceneError(f"{key}: lo and hi have different lengths")
    if any(hi <= lo for lo, hi in zip(out[0], out[1], strict=True)):
        raise SceneError(f"{key}: every hi must exceed its lo, got {v!r}")
    # the mesh generator takes no extent below the double precision epsilon
    if any(hi - lo < _MIN_EXTENT for lo, hi in zip(out[0], out[1], strict=True)):
        raise SceneError(
            f"{key}: an extent below {_MIN_EXTENT:g}, got {v!r}: scale the problem's units"
        )
    return out


def cells_check(key: str, v: Any) -> list[int]:
    """Cells per direction: an integer or a list of integers, each >= 1."""
    v = v if isinstance(v, list) else [v]
    return list_of(integer(1, MAX_CELLS), 1, 3)(key, v)


def times_check(key: str, v: Any) -> list[float]:
    """A list of times (>= 0)."""
    return list_of(number(0.0), 0, 1000)(key, v)


#: Longest ``scene.name`` (it names the default output folder ``runs/NAME``).
MAX_NAME_LENGTH = 100
_NAME_RE = re.compile(r"[A-Za-z0-9._-]+")


def scene_name(key: str, v: Any) -> str:
    """A safe single path component: letters, digits, ``-``, ``_``, ``.``; not ``.`` or ``..``."""
    string(key, v)
    if not v:
        raise SceneError(f"{key}: must not be empty")
    if len(v) > MAX_NAME_LENGTH:
        raise SceneError(f"{key}: longer than {MAX_NAME_LENGTH} characters ({len(v)})")
    if v in (".", "..") or not _NAME_RE.fullmatch(v):
        raise SceneError(
            f"{key}: {v[:40]!r} is not a safe folder name "
            "(letters, digits, '-', '_', '.'; not '.' or '..')"
        )
    return v


#: Boundary kinds of ``[flow]`` box sides, and the side names.
FLOW_BOUNDARIES = ("slip", "noslip", "inflow", "outflow")
FLOW_SIDES = ("left", "right", "bottom", "top", "front", "back")
#: Keys of a ``[phases.NAME]`` table.
PHASE_KEYS = ("density", "viscosity", "region")

SCHEMA: dict[str, dict[str, Key]] = {
    "scene": {
        "name": Key(
            scene_name,
            required=True,
            doc="scene name, the default output folder runs/NAME: letters, digits, -, _, . "
            f"(not . or ..), at most {MAX_NAME_LENGTH} characters",
        ),
        "description": Key(string, "", doc="one line shown by `pfem2x scenes`"),
        "physics": Key(choice("transport", "flow"), "transport", doc="which equations"),
        "case": Key(
            case_name,
            "",
            doc="built-in case diagnostics: " + ", ".join(CASES) + ' ("": none)',
        ),
    },
    "mesh": {
        "kind": Key(choice("interval", "rectangle", "box", "gmsh"), required=True),
        "bounds": Key(bounds_check, doc="[lo, hi] corners"),
        "cells": Key(cells_check, doc="cells per direction"),
        "diagonal": Key(choice("right", "left", "crossed", "left/right", "right/left"), "right"),
        "file": Key(string, doc="gmsh .geo/.msh file (kind = gmsh)"),
        "periodic": Key(list_of(boolean, 1, 3), doc="one bool per axis"),
        "partition": Key(
            partition_check,
            doc="MPI: rows (strips of rows), columns (rectangle: strips of columns) or "
            "[px, py] grid of sub-rectangles (rectangle; px*py = ranks); default rows",
        ),
    },
    "effects": {
        "advection": Key(boolean, False),
        "diffusion": Key(boolean, False),
        "source": Key(boolean, False),
        "reaction": Key(boolean, False),
        "gravity": Key(boolean, False),
        "viscosity": Key(boolean, False),
        "two_phase": Key(boolean, False),
        "surface_tension": Key(boolean, False),
    },
    "time": {
        "t_end": Key(number(0.0, lo_open=True), required=True),
        "dt": Key(number(0.0, lo_open=True)),
        "courant": Key(number(0.0, 1000.0, lo_open=True)),
        "max_steps": Key(integer(1), 10_000_000),
        "adaptive": Key(boolean, False, doc="re-evaluate dt every step from time.courant"),
        "max_courant": Key(
            number(0.0),
            doc="a Courant number above this is divergence (default 50 x time.courant, "
            "or 1000 with time.dt; 0: no check)",
        ),
        "max_energy_growth": Key(
            number(0.0),
            100.0,
            doc="kinetic energy above this factor x max(initial, peak, reference) is "
            "divergence (0: no check)",
        ),
        "max_growth": Key(
            number(0.0),
            10.0,
            doc="transport: max|field| above this factor x the maximum-principle bound "
            "e^(int max(0, -c) dt) (max(max|initial|, max|boundary_value|) + int max|source| dt) "
            "is divergence (0: no check)",
        ),
    },
    "method": {
        "frame": Key(choice("lagrangian", "eulerian", "characteristic"), "eulerian"),
        "particles_per_cell": Key(integer(1, 10_000), 8),
        "min_particles_per_cell": Key(integer(0, 10_000), 0),
        "max_particles_per_cell": Key(integer(0, 100_000), 0),
        "projection": Key(choice("auto", "linear", "average"), "auto"),
        "substep_courant": Key(number(0.0, 10.0, lo_open=True), 0.5),
        "substep_gradient": Key(number(0.0, 10.0), 0.1),
        "source_integration": Key(
            choice("path", "theta"),
            "path",
            doc="transport source along particle paths: path = q(x_p(s), s) at the sub-step "
            "times; theta = eq. 2.9, (1-theta) q frozen at t^n along the path + theta q^{n+1}",
        ),
        "theta": Key(number(0.0, 1.0), 0.5),
        "supg": Key(boolean, False),
        "preconditioner": Key(choice("auto", "hypre", "gamg", "jacobi", "lu", "none"), "auto"),
        "seed": Key(integer(0), 1),
    },
    "output": {
        "every": Key(number(0.0), 0.0, doc="time between field outputs (0: start and end only)"),
        "fields": Key(boolean, True),
        "particles": Key(boolean, True),
        "particle_precision": Key(choice("single", "double"), "single"),
        "png": Key(boolean, True),
        "png_times": Key(
            times_check,
            doc="times at which PNG snapshots are written (not given: t = 0 and t_end; []: none)",
        ),
        "csv": Key(boolean, True),
        "checkpoint_every": Key(
            integer(0), 0, doc="write a restart checkpoint every N steps (0: only on a signal)"
        ),
    },
    "transport": {
        "field": Key(string, "T"),
        "velocity": Key(list_of(expr_text, 1, 3)),
        "kappa": Key(expr_text, 0.0),
        "source": Key(expr_text, 0.0),
        "reaction": Key(expr_text, 0.0),
        "initial": Key(expr_text, 0.0),
        "exact": Key(expr_text),
        "boundary_value": Key(expr_text, doc="Dirichlet value on the non-periodic boundary"),
    },
    "flow": {
        "gravity": Key(list_of(number(), 1, 3), doc="gravity vector (effects.gravity)"),
        "velocity_scale": Key(expr_text, 0.0, doc="speed for time.courant while at rest"),
        "initial_velocity": Key(list_of(expr_text, 1, 3), doc="initial velocity (default 0)"),
        "exact_velocity": Key(
            list_of(expr_text, 1, 3),
            doc="exact velocity (expressions of x, y, t, params): enables velocity_l2_error = "
            "||u_h - u||_L2 / sqrt(|Omega|) (degree-6 quadrature of the expression) and its "
            "_time_avg, _final, _max metrics",
        ),
        "exact_pressure": Key(
            expr_text,
            doc="exact pressure: enables pressure_l2_error, the same norm after removing the "
            "mean over the domain from both pressures (a closed box defines p up to a constant)",
        ),
        "time_factor": Key(expr_text, 1.0, doc="reported time tau = t * time_factor"),
        "walls": Key(choice(*FLOW_BOUNDARIES), "slip", doc="kind of every box side not named"),
        **{s: Key(choice(*FLOW_BOUNDARIES), doc=f"{s} box side") for s in FLOW_SIDES},
        "inflow_velocity": Key(list_of(expr_text, 1, 3), doc="velocity on inflow sides"),
        "interface_width": Key(number(0.0, lo_open=True), 1.5, doc="smoothing half-width / H"),
        "reinit_every": Key(integer(0), 1, doc="level-set redistancing every N steps (0: never)"),
        "volume_correction": Key(
            boolean,
            False,
            doc="level set: after each re-distancing, shift phi by a constant so that the "
            "volume of phase 1 is its initial volume (the shift: volume defect / interface "
            "length, twice)",
        ),
        "max_speed": Key(expr_text, 0.0, doc="|u| above this is divergence (0: no check)"),
        "extra_pass": Key(boolean, False, doc="PFEM-2: second pass with theta = 1/2"),
        "pass_splits": Key(
            integer(0, 64),
            0,
            doc="PFEM-2, extra_pass: the second (theta = 1/2) pass sees the velocity and the "
            "source linear in time from the start of the step to the first pass's end; 0: in "
            "one move, each sub-step with the values of its own times; m > 0: in m equal "
            "parts, each with the values of its middle (1: their means over the whole step)",
        ),
        "predictor": Key(
            choice("extrapolated", "euler"),
            "extrapolated",
            doc="PFEM-2, extra_pass: the first pass; extrapolated = a theta = 1/2 pass towards "
            "u^n + dt du/dt and a^n + dt da/dt of the last step (the first step: euler), "
            "euler = along u^n with the source a^n (theta = 0, the paper)",
        ),
        "predictor_substeps": Key(
            number(1.0, 16.0),
            1.0,
            doc="PFEM-2, extra_pass: the first pass's sub-step limits (method.substep_courant "
            "and substep_gradient) times this: its move only estimates the end of the step, "
            "the second pass moves the particles; 1: the second pass's limits",
        ),
        "predictor_particles": Key(
            number(0.0, 1.0, lo_open=True),
            1.0,
            doc="PFEM-2, extra_pass: the share of each cell's particles that the first pass "
            "moves (at least one per cell): its move only estimates the end of the step, "
            "the second pass moves every particle; 1: all",
        ),
        "predictor_rtol": Key(
            number(0.0, 1.0),
            0.0,
            doc="PFEM-2, extra_pass: the relative tolerance of the first pass's viscous and "
            "pressure solves: its velocity only estimates the end of the step, the second "
            "pass's solves keep flow.rtol; 0: flow.rtol",
        ),
        "predictor_divergence_rtol": Key(
            number(0.0, 1.0),
            0.0,
            doc="PFEM-2, extra_pass, with flow.divergence_rtol > 0: the first pass's discrete "
            "projection to this relative tolerance (1: none); 0: flow.divergence_rtol",
        ),
        "viscous_step": Key(
            choice("sdirk2", "euler"),
            "sdirk2",
            doc="PFEM-2, extra_pass: the second (theta = 1/2) pass's viscous predictor; "
            "sdirk2 = the two-stage L-stable SDIRK method (second order in dt, 2 solves "
            "with one matrix), euler = backward Euler (first order); the first pass, one "
            "pass, pressure_step = total, light_source = gravity and surface tension: "
            "backward Euler",
        ),
        "pic_fraction": Key(
            number(0.0, 1.0),
            0.0,
            doc="PFEM-2: blend of particle velocities towards the mesh velocity per step "
            "(0 = pure increments, FLIP)",
        ),
        "pic_fraction_light": Key(
            number(0.0, 1.0),
            0.0,
            doc="PFEM-2, two phases: pic_fraction of the light phase (no region, e.g. air)",
        ),
        "new_particle_velocity": Key(
            choice("fit", "mesh", "mesh_deviation"),
            "fit",
            doc="PFEM-2, population control: a new particle's velocity from a least-squares "
            "fit of its cell's particles, used up to 6 Mahalanobis radii from them (fit); "
            "the mesh velocity at its position (mesh: within the cell's nodal values, no "
            "limit); or that plus the mean deviation of its cell's particles from the mesh "
            "velocity (mesh_deviation)",
        ),
        "light_source": Key(
            choice("full", "gravity"),
            "full",
            doc="PFEM-2, two phases: explicit particle source: mixture g - grad(p)/rho for "
            "all (full), or g for the light phase and g - grad(p)/rho_heavy for the heavy "
            "one (gravity; for large density ratios)",
        ),
        "mass_weighted": Key(
            boolean,
            False,
            doc="PFEM-2, two phases: project the particle velocity to the nodes weighted by "
            "the particle density (sum rho u / sum rho; for large density ratios)",
        ),
        "affine": Key(
            boolean,
            False,
            doc="PFEM-2: particles carry the mesh velocity gradient C_p of the end of each "
            "step and the projection averages u_p + C_p (x_i - x_p) (APIC transfer)",
        ),
        "density": Key(
            choice("level_set", "particles"),
            "level_set",
            doc="PFEM-2, two phases with gravity: cell densities from the cut cells of the "
            "particles' signed distance, shifted to keep the heavy volume (level_set), or "
            "from the fraction of each cell's particles in phase 1 (particles)",
        ),
        "particle_redistance": Key(
            boolean,
            True,
            doc="PFEM-2, surface tension: the particles' signed distance within 3 cells of the "
            "interface is re-distanced each step (the distance to the circles the curvature "
            "was fitted with); false: carried unchanged (the flow stretches it, and the "
            "curvature falls back to the end-point fit)",
        ),
        "pass_pressure": Key(
            choice("auto", "increment", "consistent"),
            "auto",
            doc="PFEM-2, extra_pass with explicit_pressure = consistent: the pressure of the "
            "second pass's end-of-step source; increment = the first pass's p^n + dp, "
            "consistent = solved from the first pass's velocity like p^n (one more "
            "pressure solve per step; runs the dam break at density ratio 1000); auto = "
            "consistent for two phases whose densities differ by a factor of 10 or more, "
            "else increment",
        ),
        "explicit_pressure": Key(
            choice("consistent", "lagged"),
            "consistent",
            doc="PFEM-2, pressure_step = increment: the pressure in the particles' explicit "
            "source: consistent = solved each step from u^n (div(grad(p)/rho) = div(f/rho) - "
            "grad(u):grad(u)^T, + div(nu lap(u)) with one viscous phase), lagged = the last "
            "step's p^n",
        ),
        "pressure_step": Key(
            choice("auto", "increment", "total"),
            "auto",
            doc="increment: the explicit source has -grad(p^n)/rho and the pressure step "
            "solves the increment (paper); total: the explicit source is gravity only and "
            "the pressure step solves the whole pressure each step (non-incremental; "
            "energy-stable at large density ratios, first order in dt); auto = total for "
            "the level set (eulerian) with two phases whose densities differ by a factor "
            "of 4 or more, else increment",
        ),
        "correction": Key(
            choice("velocity", "momentum"),
            "velocity",
            doc="velocity correction after the pressure step (both flow frames): velocity = "
            "u -= dt M^-1 int grad(dp).w / rho with the plain lumped mass M (the pressure "
            "equation's own 1/rho; conserves phase volumes at large density ratios); "
            "momentum = u -= dt M_rho^-1 int grad(dp).w with the lumped mass M_rho weighted "
            "by the current density",
        ),
        "surface_tension": Key(
            expr_text,
            0.0,
            doc="surface tension coefficient sigma >= 0 (a constant expression of params; "
            "effects.surface_tension): balanced capillary force with the semi-implicit "
            "Laplace-Beltrami term in the momentum operator",
        ),
        "capillary_increment": Key(
            boolean,
            False,
            doc="surface tension: the capillary force's velocity increment also passes the "
            "momentum operator (its Laplace-Beltrami term) and the pressure step is repeated: "
            "stable at steps far above the explicit capillary limit (the flow's O(dt) error "
            "grows)",
        ),
        "capillary_damping": Key(
            choice("surface", "normal"),
            "surface",
            doc="surface tension, the implicit Laplace-Beltrami term dt sigma int_Gamma "
            "grad_G u : grad_G v: surface = of the whole velocity; normal = of its normal "
            "component u.n only (the interface moves normally; tangential flow along it is "
            "not damped)",
        ),
        "rtol": Key(number(0.0, 1.0, lo_open=True), 1e-8, doc="linear solver tolerance"),
        "divergence_rtol": Key(
            auto_or(number(0.0, 1.0)),
            "auto",
            doc="pressure step: 0 = the approximate projection (the Laplacian's increment: "
            "the corrected velocity is weakly divergence-free only approximately, least at a "
            "density jump); > 0 = the discrete projection, what is left removed with the "
            "correction's own Schur complement to this relative tolerance (GMRES, "
            "flow.divergence_preconditioner, at most 30 iterations; closed boxes, "
            "correction = velocity); auto = 0.05 for PFEM-2 with two phases where the "
            "discrete projection applies (closed walls, correction = velocity), else 0",
        ),
        "divergence_preconditioner": Key(
            choice("pressure", "jacobi"),
            "pressure",
            doc="the discrete projection's GMRES preconditioner: pressure = the pressure "
            "solve's own (its AMG, set up for the same density: no second set-up), jacobi = "
            "the diagonal of its Laplacian (fewer iterations, each about a third of the time; the "
            "particles keep their phase's volume less well: the dam break's water 0.8-1.0 % "
            "against 0.2-0.4 %)",
        ),
        "quadrature_degree": Key(integer(1, 20), 4, doc="quadrature degree of the flow forms"),
    },
}
#: Meanings of keys whose ``Key`` has no doc line (kept here to keep the schema readable).
_DOCS = {
    "mesh.kind": "structured interval / rectangle (triangles) / box (tetrahedra), or a gmsh file",
    "mesh.diagonal": "how rectangle cells are split into triangles",
    "effects.advection": "transport: V.grad T (needs transport.velocity)",
    "effects.diffusion": "transport: div(kappa grad T)",
    "effects.source": "transport: the source q",
    "effects.reaction": "transport: the reaction term -c T",
    "effects.gravity": "flow: the body force flow.gravity",
    "effects.viscosity": "flow: viscous stresses",
    "effects.two_phase": "flow: two phases with [phases.*]",
    "effects.surface_tension": "flow: surface tension flow.surface_tension between the two phases",
    "time.t_end": "end time (solver units)",
    "time.dt": "fixed time step (exactly one of dt and courant)",
    "time.courant": "time step from Co = max|V| dt / H, H the shortest cell edge",
    "time.max_steps": "refuse runs with more steps",
    "method.frame": "lagrangian = PFEM-2 particles; eulerian = FEM baseline; characteristic = "
    "characteristic Galerkin (one particle per node)",
    "method.particles_per_cell": "particles seeded per cell (lagrangian)",
    "method.min_particles_per_cell": "add particles in cells with fewer (0: no control)",
    "method.max_particles_per_cell": "remove particles from cells with more (0: no control)",
    "method.projection": "particles -> mesh: linear-exact weighted least squares, or the "
    "paper's shape-function average; auto = linear for scalar transport, average for the "
    "flow velocity (the linear fit passes the FLIP velocity's sub-cell noise on to the mesh: "
    "Rayleigh-Taylor 100x400 diverged at Courant 4), linear with an outflow side (the "
    "average is biased on its one-sided nodes)",
    "method.substep_courant": "cells a particle may cross per X-IVAS sub-step",
    "method.substep_gradient": "also limit a sub-step h by h |grad u|_cell <= this "
    "(P1 velocities; the turning per sub-step; 0: off)",
    "method.theta": "theta-method weight (0 explicit, 1/2 Crank-Nicolson, 1 implicit) of every "
    "term (eulerian) or of diffusion and reaction on the mesh (characteristic, lagrangian)",
    "method.supg": "SUPG stabilisation of convection (eulerian)",
    "method.preconditioner": "linear solver preconditioner (auto: hypre if PETSc has it, "
    "else gamg; ILU for non-symmetric systems)",
    "method.seed": "random seed of particle seeding (results do not depend on the rank count)",
    "output.fields": "write fields.xdmf",
    "output.particles": "write particles.pvd (lagrangian frames)",
    "output.particle_precision": "Float32 (single) or Float64 (double) positions and fields "
    "in particles/*.vtp (last_good_particles.vtp is always double)",
    "output.png": "write PNG snapshots (false: none, whatever output.png_times says)",
    "output.csv": "write diagnostics.csv",
    "transport.field": "name of the transported field",
    "transport.velocity": "velocity components (expressions of x, y, z, t)",
    "transport.kappa": "diffusivity (effects.diffusion)",
    "transport.source": "source q (effects.source)",
    "transport.reaction": "reaction coefficient c (effects.reaction)",
    "transport.initial": "initial field",
    "transport.exact": "exact solution: enables l2_error and l2_error_time_avg",
}
for _dotted, _doc in _DOCS.items():
    _sec, _key = _dotted.split(".")
    if not SCHEMA[_sec][_key].doc:
        SCHEMA[_sec][_key] = Key(
            SCHEMA[_sec][_key].check, SCHEMA[_sec][_key].default, SCHEMA[_sec][_key].required, _doc
        )

#: Sections whose keys are free-form.
FREE_SECTIONS = {"params", "variants", "frames", "phases", "case"}
