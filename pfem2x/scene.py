"""Scenes: TOML files validated into typed objects.

A scene is a TOML file with the sections ``scene``, ``params``, ``mesh``,
``effects``, ``time``, ``method``, ``output`` and physics-specific ones
(``transport``, ``flow``, ``phases.*``). Every key is checked: unknown keys
are refused with the nearest known key suggested, types and ranges are
checked, and expressions are compiled by :mod:`pfem2x.expr` (never ``eval``).
Errors are :class:`SceneError` whose message names the key or file.
"""

from __future__ import annotations

import copy
import difflib
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

from pfem2x.expr import FUNCTIONS, VARIABLES, Expression, ExpressionError

__all__ = [
    "Scene",
    "SceneError",
    "builtin_scenes",
    "load_scene",
    "parse_override",
    "resolve_scene_path",
]

#: Where ``kind = "gmsh"`` mesh files are looked up besides the scene's folder.
MESH_DIRS = [Path(__file__).resolve().parent.parent / "meshes"]
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
    return out


def cells_check(key: str, v: Any) -> list[int]:
    """Cells per direction: an integer or a list of integers, each >= 1."""
    v = v if isinstance(v, list) else [v]
    return list_of(integer(1, MAX_CELLS), 1, 3)(key, v)


def times_check(key: str, v: Any) -> list[float]:
    """A list of times (>= 0)."""
    return list_of(number(0.0), 0, 1000)(key, v)


def strings_check(key: str, v: Any) -> list[str]:
    """A list of strings."""
    return list_of(string, 0, 100)(key, v)


#: Boundary kinds of ``[flow]`` box sides, and the side names.
FLOW_BOUNDARIES = ("slip", "noslip", "inflow", "outflow")
FLOW_SIDES = ("left", "right", "bottom", "top", "front", "back")
#: Keys of a ``[phases.NAME]`` table.
PHASE_KEYS = ("density", "viscosity", "region")

SCHEMA: dict[str, dict[str, Key]] = {
    "scene": {
        "name": Key(string, required=True, doc="scene name"),
        "description": Key(string, "", doc="one line shown by `pfem2x scenes`"),
        "physics": Key(choice("transport", "flow"), "transport", doc="which equations"),
        "case": Key(string, "", doc="built-in case diagnostics (e.g. zalesak, manufactured-1d)"),
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
        "time_factor": Key(expr_text, 1.0, doc="reported time tau = t * time_factor"),
        "walls": Key(choice(*FLOW_BOUNDARIES), "slip", doc="kind of every box side not named"),
        **{s: Key(choice(*FLOW_BOUNDARIES), doc=f"{s} box side") for s in FLOW_SIDES},
        "inflow_velocity": Key(list_of(expr_text, 1, 3), doc="velocity on inflow sides"),
        "interface_width": Key(number(0.0, lo_open=True), 1.5, doc="smoothing half-width / H"),
        "reinit_every": Key(integer(0), 1, doc="level-set redistancing every N steps (0: never)"),
        "max_speed": Key(expr_text, 0.0, doc="|u| above this is divergence (0: no check)"),
        "extra_pass": Key(boolean, False, doc="PFEM-2: second pass with theta = 1/2"),
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
        "pressure_step": Key(
            choice("increment", "total"),
            "increment",
            doc="increment: the explicit source has -grad(p^n)/rho and the pressure step "
            "solves the increment (paper); total: the explicit source is gravity only and "
            "the pressure step solves the whole pressure each step (non-incremental; "
            "energy-stable at large density ratios, first order in dt)",
        ),
        "correction": Key(
            choice("velocity", "momentum"),
            "velocity",
            doc="velocity correction of the pressure step: u -= dt M^-1 int grad(dp).w / rho "
            "(velocity: the same 1/rho as the pressure equation, conserves phase volumes at "
            "large density ratios) or u -= dt M_rho^-1 int grad(dp).w (momentum: rho-weighted "
            "lumped mass, pfem2x < 0.3)",
        ),
        "rtol": Key(number(0.0, 1.0, lo_open=True), 1e-8, doc="linear solver tolerance"),
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
    "Rayleigh-Taylor 100x400 diverged at Courant 4)",
    "method.substep_courant": "cells a particle may cross per X-IVAS sub-step",
    "method.substep_gradient": "also limit a sub-step h by h |grad u|_cell <= this "
    "(P1 velocities; the turning per sub-step; 0: off)",
    "method.theta": "theta-method weight (eulerian; 0 explicit, 1/2 Crank-Nicolson, 1 implicit)",
    "method.supg": "SUPG stabilisation of convection (eulerian)",
    "method.preconditioner": "linear solver preconditioner (auto: hypre if PETSc has it, "
    "else gamg; ILU for non-symmetric systems)",
    "method.seed": "random seed of particle seeding (results do not depend on the rank count)",
    "output.fields": "write fields.xdmf",
    "output.particles": "write particles.pvd (lagrangian frames)",
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
FREE_SECTIONS = {"params", "variants", "phases", "case"}


@dataclass
class Scene:
    """A validated scene.

    The sections are plain dicts with every key present (defaults filled in);
    ``expr(section, key)`` returns compiled expressions.
    """

    name: str
    raw: dict[str, Any]
    source: str
    base_dir: Path
    params: dict[str, float] = field(default_factory=dict)
    sections: dict[str, dict[str, Any]] = field(default_factory=dict)

    def __getitem__(self, section: str) -> dict[str, Any]:
        return self.sections[section]

    @property
    def frame(self) -> str:
        """The method's frame."""
        return self.sections["method"]["frame"]

    @property
    def effects(self) -> dict[str, bool]:
        """Active effects."""
        return self.sections["effects"]

    def expr(self, section: str, key: str) -> Expression:
        """Compile ``[section].key`` as a scalar expression."""
        return Expression(self.sections[section][key], self.params, f"{section}.{key}")

    def vector_expr(self, section: str, key: str, gdim: int) -> list[Expression]:
        """Compile ``[section].key`` as ``gdim`` component expressions."""
        v = self.sections[section][key]
        if v is None:
            raise SceneError(f"{section}.{key}: required")
        if len(v) < gdim:
            raise SceneError(f"{section}.{key}: expected {gdim} components, got {len(v)}")
        return [Expression(s, self.params, f"{section}.{key}[{i}]") for i, s in enumerate(v[:gdim])]

    @property
    def gdim(self) -> int:
        """Geometric dimension implied by the mesh section."""
        m = self.sections["mesh"]
        if m["kind"] == "gmsh":
            return int(m.get("_gdim", 2))
        return {"interval": 1, "rectangle": 2, "box": 3}[m["kind"]]

    def resolved_toml(self) -> str:
        """The scene with defaults and overrides applied, as TOML text."""
        out: dict[str, Any] = {"params": dict(self.params)} if self.params else {}
        physics = self.sections["scene"]["physics"]
        for sec, d in self.sections.items():
            if (
                sec in ("transport", "flow", "phases")
                and sec != physics
                and not (sec == "phases" and physics == "flow")
            ):
                continue  # another physics' defaults
            out[sec] = {k: v for k, v in d.items() if not k.startswith("_")}
        return dump_toml(out)


# --------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------
def builtin_dir() -> Path:
    """Folder of the built-in scenes."""
    return Path(str(resources.files("pfem2x") / "scenes"))


def builtin_scenes() -> dict[str, Path]:
    """Built-in scene names → files."""
    return {p.stem: p for p in sorted(builtin_dir().glob("*.toml"))}


def resolve_scene_path(name_or_path: str) -> Path:
    """A path to a scene file, or a built-in scene name."""
    p = Path(name_or_path)
    known = builtin_scenes()
    if (
        name_or_path in known and not p.is_file()
    ):  # a folder of that name (e.g. outputs) does not hide it
        return known[name_or_path]
    if p.suffix == ".toml" or p.exists() or "/" in name_or_path:
        if not p.exists():
            raise SceneError(f"{name_or_path}: no such scene file")
        if not p.is_file():
            raise SceneError(f"{name_or_path}: not a file")
        return p
    near = difflib.get_close_matches(name_or_path, list(known), n=1)
    hint = f" (did you mean {near[0]!r}?)" if near else ""
    raise SceneError(
        f"{name_or_path}: no such scene file or built-in scene{hint}; see `pfem2x scenes`"
    )


def parse_override(text: str) -> tuple[list[str], Any]:
    """Parse ``--set KEY=VALUE``: a dotted key and a TOML value (bare words are strings)."""
    if "=" not in text:
        raise SceneError(f"--set {text}: expected KEY=VALUE, e.g. time.courant=8")
    key, _, val = text.partition("=")
    key = key.strip()
    parts = key.split(".")
    if not key or any(not p.strip() for p in parts):
        raise SceneError(f"--set {text}: bad key {key!r}")
    val = val.strip()
    try:
        value = tomllib.loads(f"v = {val}")["v"]
    except tomllib.TOMLDecodeError:
        if val and all(ch.isalnum() or ch in "_-/." for ch in val) and not val[0].isdigit():
            value = val
        else:
            raise SceneError(f"--set {text}: cannot read the value {val!r} (TOML syntax)") from None
    return [p.strip() for p in parts], value


def _set_dotted(raw: dict, parts: list[str], value: Any, where: str) -> None:
    d = raw
    for p in parts[:-1]:
        nxt = d.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise SceneError(f"{where}: {p!r} is not a section")
        d = nxt
    d[parts[-1]] = value


def load_scene(
    name_or_path: str | Path,
    overrides: list[str] | None = None,
    variant: str | None = None,
) -> Scene:
    """Read, override and validate a scene.

    Parameters
    ----------
    name_or_path:
        A scene file or a built-in scene name.
    overrides:
        ``KEY=VALUE`` strings (as given to ``--set``).
    variant:
        Apply the scene's ``[variants.NAME]`` table (dotted keys) first.

    Raises
    ------
    SceneError
        With a message that names the file or key.
    """
    path = resolve_scene_path(str(name_or_path))
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(f"{path}: cannot read ({exc.__class__.__name__})") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from None
    raw = copy.deepcopy(raw)
    if variant:
        variants = raw.get("variants", {})
        if variant not in variants:
            known = ", ".join(sorted(variants)) or "none"
            raise SceneError(f"--variant {variant}: {path.name} has no such variant (has: {known})")
        for k, v in variants[variant].items():
            _set_dotted(raw, k.split("."), v, f"variants.{variant}.{k}")
    step_keys: set[str] = set()
    for ov in overrides or []:
        parts, value = parse_override(ov)
        _set_dotted(raw, parts, value, f"--set {ov}")
        if parts[0] == "time" and len(parts) == 2 and parts[1] in ("dt", "courant"):
            step_keys.add(parts[1])
    # `--set time.dt=...` on a scene that sets time.courant (or the reverse) replaces it;
    # giving both on the command line is still refused by validation.
    if len(step_keys) == 1 and isinstance(raw.get("time"), dict):
        other = "courant" if "dt" in step_keys else "dt"
        raw["time"].pop(other, None)
    return validate(raw, source=str(path), base_dir=path.parent)


def _unknown(key: str, known: list[str], where: str) -> SceneError:
    near = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
    hint = f" (did you mean {where}{near[0]}?)" if near else ""
    return SceneError(f"{where}{key}: unknown key{hint}")


def validate(raw: dict[str, Any], source: str = "<scene>", base_dir: Path | None = None) -> Scene:
    """Validate a raw scene dict into a :class:`Scene`."""
    base_dir = base_dir or Path.cwd()
    for sec in raw:
        if sec not in SCHEMA and sec not in FREE_SECTIONS:
            raise _unknown(sec, list(SCHEMA) + sorted(FREE_SECTIONS), "")
    for sec in SCHEMA:
        if sec in raw and not isinstance(raw[sec], dict):
            raise SceneError(f"{sec}: expected a table [{sec}], got {_type_name(raw[sec])}")
    params = _validate_params(raw.get("params", {}))
    sections: dict[str, dict[str, Any]] = {}
    for sec, keys in SCHEMA.items():
        given = raw.get(sec, {})
        out: dict[str, Any] = {}
        for k, v in given.items():
            if k not in keys:
                raise _unknown(k, list(keys), f"{sec}.")
            out[k] = keys[k].check(f"{sec}.{k}", v)
        for k, spec in keys.items():
            if k not in out:
                if spec.required:
                    raise SceneError(f"{sec}.{k}: required")
                out[k] = copy.deepcopy(spec.default)
        sections[sec] = out
    for sec in ("phases",):
        if sec in raw:
            if not isinstance(raw[sec], dict):
                raise SceneError(f"{sec}: expected a table")
            sections[sec] = raw[sec]
    scene = Scene(
        name=sections["scene"]["name"],
        raw=raw,
        source=source,
        base_dir=base_dir,
        params=params,
        sections=sections,
    )
    _check_consistency(scene)
    return scene


def _validate_params(p: Any) -> dict[str, float]:
    if not isinstance(p, dict):
        raise SceneError("params: expected a table [params]")
    out = {}
    reserved = set(VARIABLES) | set(FUNCTIONS) | {"pi", "e"}
    for k, v in p.items():
        if not k.isidentifier() or k.startswith("_"):
            raise SceneError(
                f"params.{k}: a parameter name must be an identifier not starting with _"
            )
        if k in reserved:
            raise SceneError(f"params.{k}: the name is reserved (a variable, constant or function)")
        out[k] = number()(f"params.{k}", v)
    return out


def _check_consistency(scene: Scene) -> None:
    m, t, meth, eff = scene["mesh"], scene["time"], scene["method"], scene["effects"]
    dims = {"interval": 1, "rectangle": 2, "box": 3}
    if m["kind"] in dims:
        d = dims[m["kind"]]
        if m["bounds"] is None:
            raise SceneError("mesh.bounds: required for kind = " + repr(m["kind"]))
        if m["cells"] is None:
            raise SceneError("mesh.cells: required for kind = " + repr(m["kind"]))
        if len(m["bounds"][0]) != d:
            raise SceneError(f"mesh.bounds: a {m['kind']} needs {d} coordinates per corner")
        if len(m["cells"]) != d:
            raise SceneError(f"mesh.cells: a {m['kind']} needs {d} entries, got {len(m['cells'])}")
        n = math.prod(m["cells"]) * {1: 1, 2: 2, 3: 6}[d]
        if m["diagonal"] == "crossed" and d == 2:
            n *= 2
        if n > MAX_CELLS:
            raise SceneError(f"mesh.cells: {n} cells exceed the limit of {MAX_CELLS}")
        m["_num_cells"] = n
    else:
        if not m["file"]:
            raise SceneError("mesh.file: required for kind = 'gmsh'")
        m["file"] = str(_find_mesh_file(m["file"], scene.base_dir))
        m["_num_cells"] = None
    if m["periodic"] is not None and m["kind"] in dims and len(m["periodic"]) != dims[m["kind"]]:
        raise SceneError(f"mesh.periodic: needs {dims[m['kind']]} entries")
    if (t["dt"] is None) == (t["courant"] is None):
        raise SceneError("time: give exactly one of time.dt and time.courant")
    if t["dt"] is not None and t["dt"] > t["t_end"]:
        raise SceneError(f"time.dt: {t['dt']:g} is larger than time.t_end = {t['t_end']:g}")
    if t["dt"] is not None and t["t_end"] / t["dt"] > t["max_steps"]:
        raise SceneError(
            f"time.dt: {t['t_end'] / t['dt']:.3g} steps exceed time.max_steps = {t['max_steps']}"
        )
    lo, hi = meth["min_particles_per_cell"], meth["max_particles_per_cell"]
    if hi and lo > hi:
        raise SceneError("method.min_particles_per_cell: larger than method.max_particles_per_cell")
    if meth["frame"] == "lagrangian" and m["_num_cells"]:
        need = m["_num_cells"] * max(meth["particles_per_cell"], hi) * BYTES_PER_PARTICLE
        if need > MAX_PARTICLE_BYTES:
            raise SceneError(
                f"method.particles_per_cell: {m['_num_cells']} cells x "
                f"{meth['particles_per_cell']} particles would need ~{need / 1024**3:.0f} GiB "
                f"(limit {MAX_PARTICLE_BYTES / 1024**3:.0f} GiB)"
            )
    phys = scene["scene"]["physics"]
    if phys == "transport":
        tr = scene["transport"]
        needs = {"advection": "velocity"}
        for eff_name, key in needs.items():
            if eff[eff_name] and tr[key] is None:
                raise SceneError(f"transport.{key}: required when effects.{eff_name} = true")
        if t["courant"] is not None and not eff["advection"]:
            raise SceneError("time.courant: needs effects.advection = true (use time.dt)")
    if phys == "flow":
        _check_flow(scene)
    # Compile every expression now so that bad ones are refused by `check`.
    gdim = {"interval": 1, "rectangle": 2, "box": 3}.get(m["kind"], 3)
    try:
        for sec in ("transport",):
            for k, v in scene[sec].items():
                if v is None or k == "field":
                    continue
                if isinstance(v, list):
                    scene.vector_expr(sec, k, min(gdim, len(v)))
                else:
                    e = scene.expr(sec, k)
                    if k == "kappa" and e.constant and e.value() < 0:
                        raise SceneError(f"transport.kappa: must be >= 0, got {e.value():g}")
    except ExpressionError as exc:
        raise SceneError(str(exc)) from None


def _check_flow(scene: Scene) -> None:
    """``[flow]`` and ``[phases.*]``: densities > 0, viscosities >= 0, compiled expressions."""
    phases = scene.sections.get("phases", {})
    two = scene.effects["two_phase"]
    if not phases:
        raise SceneError("phases: a flow scene needs at least one [phases.NAME] table")
    for name, ph in phases.items():
        if not isinstance(ph, dict):
            raise SceneError(f"phases.{name}: expected a table [phases.{name}]")
        for k in ph:
            if k not in PHASE_KEYS:
                raise _unknown(k, list(PHASE_KEYS), f"phases.{name}.")
        if "density" not in ph:
            raise SceneError(f"phases.{name}.density: required")
        ph["density"] = number(0.0, lo_open=True)(f"phases.{name}.density", ph["density"])
        ph["viscosity"] = number(0.0)(f"phases.{name}.viscosity", ph.get("viscosity", 0.0))
        if "region" in ph:
            expr_text(f"phases.{name}.region", ph["region"])
    with_region = [n for n, ph in phases.items() if "region" in ph]
    if two and (len(phases) != 2 or len(with_region) != 1):
        raise SceneError(
            "phases: effects.two_phase needs exactly two [phases.*] tables, "
            "one of them with a region"
        )
    if not two and len(phases) != 1:
        raise SceneError("phases: more than one phase needs effects.two_phase = true")
    fl = scene["flow"]
    if scene.effects["gravity"] and fl["gravity"] is None:
        raise SceneError("flow.gravity: required when effects.gravity = true")
    t = scene["time"]
    try:
        for k in ("velocity_scale", "time_factor", "max_speed"):
            scene.expr("flow", k)
        for k in ("initial_velocity", "inflow_velocity"):
            if fl[k] is not None:
                scene.vector_expr("flow", k, min(scene.gdim, len(fl[k])))
        for name, ph in phases.items():
            if "region" in ph:
                Expression(ph["region"], scene.params, f"phases.{name}.region")
        vs = scene.expr("flow", "velocity_scale")
    except ExpressionError as exc:
        raise SceneError(str(exc)) from None
    if t["courant"] is not None and fl["initial_velocity"] is None:
        if not vs.constant or vs.value() <= 0:
            raise SceneError(
                "flow.velocity_scale: time.courant on a fluid at rest needs a constant "
                "velocity_scale > 0 (or give time.dt)"
            )


def _find_mesh_file(name: str, base_dir: Path) -> Path:
    p = Path(name)
    cands = [p] if p.is_absolute() else [base_dir / p, Path.cwd() / p] + [d / p for d in MESH_DIRS]
    for c in cands:
        if c.is_file():
            return c.resolve()
    raise SceneError(
        f"mesh.file: {name}: no such file (looked in {', '.join(str(c.parent) for c in cands)})"
    )


def dump_toml(data: Mapping[str, Any]) -> str:
    """Write a (nested) dict as TOML text (tables, arrays, strings, numbers, booleans)."""

    def val(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, int | float):
            return repr(v)
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list | tuple):
            return "[" + ", ".join(val(x) for x in v) + "]"
        raise TypeError(type(v))

    lines: list[str] = []

    def table(prefix: str, d: Mapping[str, Any]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict) and v is not None}
        subs = {k: v for k, v in d.items() if isinstance(v, dict)}
        if prefix and (scalars or not subs):
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {val(v)}")
        if scalars:
            lines.append("")
        for k, v in subs.items():
            table(f"{prefix}.{k}" if prefix else k, v)

    table("", data)
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------
# Reference documentation (docs/SCENES.md is generated from the schema)
# --------------------------------------------------------------------------
def _kind(check: Callable[[str, Any], Any]) -> str:
    base = getattr(check, "__qualname__", "").split(".")[0]
    cells = [c.cell_contents for c in (getattr(check, "__closure__", None) or ())]
    if base == "choice":
        opts = next((c for c in cells if isinstance(c, tuple)), ())
        return " \\| ".join(f"`{o}`" for o in opts)
    if base == "list_of":
        inner = next((c for c in cells if callable(c)), None)
        return f"list of {_kind(inner)}" if inner else "list"
    names = {
        "number": "number",
        "integer": "integer",
        "boolean": "boolean",
        "string": "string",
        "expr_text": "expression or number",
        "bounds_check": "[lo, hi] corners",
        "cells_check": "integer or list of integers",
        "times_check": "list of times",
        "strings_check": "list of strings",
    }
    return names.get(base, base or "value")


def schema_markdown() -> str:
    """Every scene key with its type, default and meaning, as markdown (docs/SCENES.md)."""
    lines = [
        "# Scene keys",
        "",
        "Generated from `pfem2x/scene.py` by `python -m pfem2x.scene > docs/SCENES.md`",
        "(a test checks that this file is current). Expressions: see README.md.",
        "",
    ]
    for sec, keys in SCHEMA.items():
        lines += [f"## [{sec}]", "", "| key | type | default | meaning |", "|---|---|---|---|"]
        for k, spec in keys.items():
            default = (
                "**required**"
                if spec.required
                else ("" if spec.default is None else f"`{spec.default!r}`")
            )
            doc = spec.doc.replace("|", "\\|")
            lines.append(f"| `{sec}.{k}` | {_kind(spec.check)} | {default} | {doc} |")
        lines.append("")
    lines += [
        "## [phases.NAME] (flow)",
        "",
        "| key | type | default | meaning |",
        "|---|---|---|---|",
        "| `density` | number > 0 | **required** | the phase's density |",
        "| `viscosity` | number >= 0 | `0.0` | dynamic viscosity |",
        "| `region` | expression | | where the phase is at t = 0 (truthy); exactly one of two |",
        "",
        "## [params], [variants.NAME]",
        "",
        "`[params]`: named numbers usable in every expression (identifiers, not `x y z t`, not",
        "a function or constant name). `[variants.NAME]`: dotted keys applied by",
        "`--variant NAME` before any `--set`.",
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    print(schema_markdown(), end="")
