"""Scenes: TOML files validated into typed objects.

A scene is a TOML file with the sections ``scene``, ``params``, ``mesh``,
``effects``, ``time``, ``method``, ``output`` and physics-specific ones
(``transport``, ``flow``, ``phases.*``). Every key is checked against
:data:`pfem2x.scene_schema.SCHEMA`: unknown keys are refused with the nearest
known key suggested, types and ranges are checked, every check that involves
several keys is made here (before any mesh or solver is built), and
expressions are compiled by :mod:`pfem2x.expr` (never ``eval``). Errors are
:class:`SceneError` whose message names the key or file.

A validated :class:`Scene` holds one frozen dataclass per section
(:mod:`pfem2x.scene_sections`): ``scene.time.t_end``, ``scene.flow.gravity``,
``scene.phases["heavy"].density``; ``scene["time"]["t_end"]`` still works.
"""

from __future__ import annotations

import copy
import difflib
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

from pfem2x.expr import FUNCTIONS, VARIABLES, Expression, ExpressionError
from pfem2x.scene_layers import (
    Layer,
    apply_layers,
    check_frames,
    check_variants,
    flatten,
    frame_layers,
)
from pfem2x.scene_readers import PHYSICS_EFFECTS
from pfem2x.scene_reference import schema_markdown
from pfem2x.scene_schema import (
    BYTES_PER_PARTICLE,
    FLOW_BOUNDARIES,
    FLOW_SIDES,
    FREE_SECTIONS,
    MAX_CELLS,
    MAX_PARTICLE_BYTES,
    PHASE_KEYS,
    SCHEMA,
    Key,
    SceneError,
    _type_name,
    expr_text,
    number,
)
from pfem2x.scene_sections import (
    EffectsSection,
    FlowSection,
    MeshSection,
    MethodSection,
    OutputSection,
    PhaseSection,
    SceneSection,
    TimeSection,
    TransportSection,
)

__all__ = [
    "FLOW_BOUNDARIES",
    "FLOW_SIDES",
    "SCHEMA",
    "Key",
    "Scene",
    "SceneError",
    "builtin_scenes",
    "check_components",
    "dump_toml",
    "toml_value",
    "load_scene",
    "parse_override",
    "resolve_scene_path",
    "schema_markdown",
    "validate",
]

#: Where ``kind = "gmsh"`` mesh files are looked up besides the scene's folder.
MESH_DIRS = [Path(__file__).resolve().parent.parent / "meshes"]
#: Geometric dimension of the structured mesh kinds.
_DIMS = {"interval": 1, "rectangle": 2, "box": 3}
#: The section dataclass of each schema section.
SECTION_TYPES = {
    "scene": SceneSection,
    "mesh": MeshSection,
    "effects": EffectsSection,
    "time": TimeSection,
    "method": MethodSection,
    "output": OutputSection,
    "transport": TransportSection,
    "flow": FlowSection,
}


@dataclass
class Scene:
    """A validated scene: one frozen, typed object per section.

    ``scene.mesh``, ``scene.time``, ... are the sections of
    :mod:`pfem2x.scene_sections` (every key present, defaults filled in);
    ``scene.phases`` maps phase names to :class:`PhaseSection` (flow; empty for
    transport). ``scene["time"]["t_end"]`` reads the same values through the
    sections' mapping view (lists instead of tuples). ``expr(section, key)``
    returns compiled expressions.
    """

    name: str
    raw: dict[str, Any]
    source: str
    base_dir: Path
    params: dict[str, float]
    scene: SceneSection
    mesh: MeshSection
    effects: EffectsSection
    time: TimeSection
    method: MethodSection
    output: OutputSection
    transport: TransportSection
    flow: FlowSection
    phases: Mapping[str, PhaseSection]
    #: Section → its keys in the order :meth:`resolved_toml` writes them (given first).
    key_order: dict[str, tuple[str, ...]] = field(default_factory=dict, repr=False)
    #: ``"key = value"`` of the scene's ``[frames.FRAME]`` table that the run took
    #: (:func:`load_scene`; empty for a scene validated from a dict).
    frame_keys: tuple[str, ...] = ()

    @property
    def sections(self) -> dict[str, Mapping[str, Any]]:
        """Section name → section (``phases``: name → phase, flow scenes only)."""
        out: dict[str, Mapping[str, Any]] = {sec: getattr(self, sec) for sec in SECTION_TYPES}
        if self.scene.physics == "flow":
            out["phases"] = self.phases
        return out

    def __getitem__(self, section: str) -> Mapping[str, Any]:
        """``scene["time"]`` is ``scene.time`` (read-only; kept for older callers)."""
        return self.sections[section]

    @property
    def physics(self) -> str:
        """``scene.physics``: which equations."""
        return self.scene.physics

    @property
    def frame(self) -> str:
        """The method's frame."""
        return self.method.frame

    def expr(self, section: str, key: str) -> Expression:
        """Compile ``[section].key`` as a scalar expression."""
        return Expression(getattr(getattr(self, section), key), self.params, f"{section}.{key}")

    def vector_expr(self, section: str, key: str, gdim: int) -> list[Expression]:
        """Compile ``[section].key`` as ``gdim`` component expressions."""
        v = getattr(getattr(self, section), key)
        if v is None:
            raise SceneError(f"{section}.{key}: required")
        check_components(f"{section}.{key}", v, gdim)
        return [Expression(s, self.params, f"{section}.{key}[{i}]") for i, s in enumerate(v)]

    @property
    def gdim(self) -> int:
        """Geometric dimension implied by the mesh section (2 for gmsh files)."""
        return _DIMS.get(self.mesh.kind, 2)

    def resolved_toml(self) -> str:
        """The scene with defaults and overrides applied, as TOML text."""
        out: dict[str, Any] = {"params": dict(self.params)} if self.params else {}
        physics = self.physics
        for sec, d in self.sections.items():
            if sec in ("transport", "flow") and sec != physics:
                continue  # another physics' defaults
            if sec == "phases":
                out[sec] = {n: ph.as_dict() for n, ph in d.items()}
            else:
                out[sec] = {k: d[k] for k in self.key_order.get(sec, tuple(d))}
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
        Apply the scene's ``[variants.NAME]`` table (dotted keys) before ``overrides``
        and after the ``[frames.FRAME]`` table of the run's frame, then the variant's
        own ``[variants.NAME.frames.FRAME]`` table of that frame
        (:mod:`pfem2x.scene_layers`).

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
    vlayer: Layer = []
    vframes: dict[str, Layer] = {}
    if variant:
        variants = raw.get("variants", {})
        if not isinstance(variants, dict):
            raise SceneError("variants: expected tables [variants.NAME] of dotted keys")
        if variant not in variants:
            known = ", ".join(sorted(variants)) or "none"
            raise SceneError(f"--variant {variant}: {path.name} has no such variant (has: {known})")
        if not isinstance(variants[variant], dict):
            raise SceneError(f"variants.{variant}: expected a table of dotted keys")
        table = dict(variants[variant])
        vframes = frame_layers(raw, table.pop("frames", {}), f"variants.{variant}.frames")
        vlayer = flatten(table, f"variants.{variant}")
    sets: Layer = []
    for ov in overrides or []:
        parts, value = parse_override(ov)
        if parts[0] in ("frames", "variants"):
            raise SceneError(
                f"--set {ov}: [{parts[0]}] tables are read from the scene file only "
                "(set the key itself, e.g. --set flow.rtol=1e-6)"
            )
        # a table value sets its leaves (as a variant's nested tables do)
        leaves = flatten({".".join(parts): value}, "--set") if isinstance(value, dict) else []
        sets += [(p, v, f"--set {ov}") for p, v, _ in leaves] or [(parts, value, f"--set {ov}")]
    kept = apply_layers(raw, vlayer, sets, vframes)
    scene = validate(raw, source=str(path), base_dir=path.parent)
    scene.frame_keys = tuple(f"{'.'.join(p)} = {toml_value(v)}" for p, v, _ in kept)
    return scene


def check_components(key: str, v: Any, gdim: int) -> None:
    """Refuse a vector-valued key that has not exactly one component per mesh dimension.

    Parameters
    ----------
    key
        The key, as the message names it (``flow.gravity``).
    v
        Its value, a list or tuple.
    gdim
        The mesh's geometric dimension.

    Raises
    ------
    SceneError
        When ``len(v) != gdim``.
    """
    if len(v) != gdim:
        what = "1 component" if gdim == 1 else f"{gdim} components"
        raise SceneError(f"{key}: expected {what} (one per mesh dimension), got {len(v)}")


def _unknown(key: str, known: list[str], where: str) -> SceneError:
    near = difflib.get_close_matches(key, known, n=1, cutoff=0.5)
    hint = f" (did you mean {where}{near[0]}?)" if near else ""
    return SceneError(f"{where}{key}: unknown key{hint}")


def validate(raw: dict[str, Any], source: str = "<scene>", base_dir: Path | None = None) -> Scene:
    """Validate a raw scene dict into a :class:`Scene` (``raw`` is not modified).

    ``[frames.*]`` and every ``[variants.*]`` table are checked, not applied:
    :func:`load_scene` applies them.

    Raises
    ------
    SceneError
        On the first invalid key, with a message that names it.
    """
    base_dir = base_dir or Path.cwd()
    for sec in raw:
        if sec not in SCHEMA and sec not in FREE_SECTIONS:
            raise _unknown(sec, list(SCHEMA) + sorted(FREE_SECTIONS), "")
    for sec in SCHEMA:
        if sec in raw and not isinstance(raw[sec], dict):
            raise SceneError(f"{sec}: expected a table [{sec}], got {_type_name(raw[sec])}")
    check_frames(raw)
    check_variants(raw)
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
    num_cells = _check_consistency(sections, base_dir)
    phases: dict[str, PhaseSection] = {}
    if sections["scene"]["physics"] == "flow":
        phases = _validate_phases(raw.get("phases"), sections["effects"]["two_phase"])
        _check_flow(sections)
    _check_case(sections, params)
    typed = {
        sec: cls.from_dict(
            {k: sections[sec][k] for k in SCHEMA[sec]},
            **({"num_cells": num_cells} if sec == "mesh" else {}),
        )
        for sec, cls in SECTION_TYPES.items()
    }
    scene = Scene(
        name=sections["scene"]["name"],
        raw=raw,
        source=source,
        base_dir=base_dir,
        params=params,
        phases=MappingProxyType(phases),
        key_order={sec: tuple(d) for sec, d in sections.items()},
        **typed,
    )
    _check_expressions(scene)
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


def _check_consistency(s: dict[str, dict[str, Any]], base_dir: Path) -> int | None:
    """Checks across the keys of ``[mesh]``, ``[time]``, ``[method]`` and ``[transport]``.

    Resolves ``mesh.file`` in place; returns the number of cells of a structured mesh.
    """
    m, t, meth, eff = s["mesh"], s["time"], s["method"], s["effects"]
    num_cells = None
    if m["kind"] in _DIMS:
        d = _DIMS[m["kind"]]
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
        num_cells = n
    else:
        if not m["file"]:
            raise SceneError("mesh.file: required for kind = 'gmsh'")
        m["file"] = str(_find_mesh_file(m["file"], base_dir))
    if m["periodic"] is not None and m["kind"] in _DIMS and len(m["periodic"]) != _DIMS[m["kind"]]:
        raise SceneError(f"mesh.periodic: needs {_DIMS[m['kind']]} entries")
    part = m["partition"]
    if part is not None and part != "rows" and m["kind"] != "rectangle":
        what = '"columns"' if part == "columns" else "a [px, py] grid"
        raise SceneError(f"mesh.partition: {what} is only available for rectangles")
    if (t["dt"] is None) == (t["courant"] is None):
        raise SceneError("time: give exactly one of time.dt and time.courant")
    if t["adaptive"] and t["courant"] is None:
        raise SceneError(
            "time.adaptive: re-evaluates the step from time.courant, and this scene gives "
            "a fixed time.dt; give time.courant instead (or time.adaptive = false)"
        )
    if t["dt"] is not None and t["dt"] > t["t_end"]:
        raise SceneError(f"time.dt: {t['dt']:g} is larger than time.t_end = {t['t_end']:g}")
    if t["dt"] is not None and t["t_end"] / t["dt"] > t["max_steps"]:
        raise SceneError(
            f"time.dt: {t['t_end'] / t['dt']:.3g} steps exceed time.max_steps = {t['max_steps']}"
        )
    lo, hi = meth["min_particles_per_cell"], meth["max_particles_per_cell"]
    if hi and lo > hi:
        raise SceneError("method.min_particles_per_cell: larger than method.max_particles_per_cell")
    if meth["frame"] == "lagrangian" and num_cells:
        need = num_cells * max(meth["particles_per_cell"], hi) * BYTES_PER_PARTICLE
        if need > MAX_PARTICLE_BYTES:
            raise SceneError(
                f"method.particles_per_cell: {num_cells} cells x "
                f"{meth['particles_per_cell']} particles would need ~{need / 1024**3:.0f} GiB "
                f"(limit {MAX_PARTICLE_BYTES / 1024**3:.0f} GiB)"
            )
    physics = s["scene"]["physics"]
    for name, on in eff.items():
        if on and name not in PHYSICS_EFFECTS[physics]:
            other = next(p for p, names in PHYSICS_EFFECTS.items() if name in names)
            raise SceneError(
                f"effects.{name}: an effect of {other} scenes, not of this {physics} scene "
                f"(its effects: {', '.join(PHYSICS_EFFECTS[physics])})"
            )
    if physics == "transport":
        if eff["advection"] and s["transport"]["velocity"] is None:
            raise SceneError("transport.velocity: required when effects.advection = true")
        if t["courant"] is not None and not eff["advection"]:
            raise SceneError("time.courant: needs effects.advection = true (use time.dt)")
    return num_cells


def _validate_phases(raw: Any, two: bool) -> dict[str, PhaseSection]:
    """``[phases.*]``: densities > 0, viscosities >= 0, one region per two phases."""
    if raw is not None and not isinstance(raw, dict):
        raise SceneError("phases: expected a table")
    if not raw:
        raise SceneError("phases: a flow scene needs at least one [phases.NAME] table")
    phases = {}
    for name, ph in raw.items():
        if not isinstance(ph, dict):
            raise SceneError(f"phases.{name}: expected a table [phases.{name}]")
        for k in ph:
            if k not in PHASE_KEYS:
                raise _unknown(k, list(PHASE_KEYS), f"phases.{name}.")
        if "density" not in ph:
            raise SceneError(f"phases.{name}.density: required")
        density = number(0.0, lo_open=True)(f"phases.{name}.density", ph["density"])
        viscosity = number(0.0)(f"phases.{name}.viscosity", ph.get("viscosity", 0.0))
        region = expr_text(f"phases.{name}.region", ph["region"]) if "region" in ph else None
        order = tuple(ph) + (() if "viscosity" in ph else ("viscosity",))
        phases[name] = PhaseSection(name, density, viscosity, region, order)
    with_region = [n for n, ph in phases.items() if ph.region is not None]
    if two and (len(phases) != 2 or len(with_region) != 1):
        raise SceneError(
            "phases: effects.two_phase needs exactly two [phases.*] tables, "
            "one of them with a region"
        )
    if not two and len(phases) != 1:
        raise SceneError("phases: more than one phase needs effects.two_phase = true")
    return phases


def _check_flow(s: dict[str, dict[str, Any]]) -> None:
    """Checks across ``[flow]``, ``[mesh]`` and ``[method]`` (those the flow solvers make)."""
    fl, m, frame = s["flow"], s["mesh"], s["method"]["frame"]
    if s["effects"]["gravity"] and fl["gravity"] is None:
        raise SceneError("flow.gravity: required when effects.gravity = true")
    if frame not in ("eulerian", "lagrangian"):
        raise SceneError(f"method.frame: the {frame!r} flow frame is not available yet")
    sides = {side: fl[side] or fl["walls"] for side in FLOW_SIDES[:4]}  # 2D: the box sides
    if frame == "lagrangian" and s["effects"]["two_phase"]:
        for side, kind in sides.items():
            if kind not in ("slip", "noslip"):
                raise SceneError(
                    f"flow.{side if fl[side] else 'walls'}: {kind!r} sides are not available "
                    "in the lagrangian flow frame with two phases yet (slip, noslip)"
                )
    if m["kind"] in ("interval", "box"):
        raise SceneError("mesh.kind: flow is available on 2D meshes only (for now)")
    if fl["gravity"] is not None and m["kind"] in _DIMS:  # a gmsh mesh: FlowProblem checks
        check_components("flow.gravity", fl["gravity"], _DIMS[m["kind"]])
    if m["periodic"] is not None and any(m["periodic"]):
        raise SceneError("mesh.periodic: periodic flow is not available yet")
    if "inflow" in sides.values() and fl["inflow_velocity"] is None:
        raise SceneError("flow.inflow_velocity: required with an inflow side")
    if s["effects"]["surface_tension"]:
        if not s["effects"]["two_phase"]:
            raise SceneError("effects.surface_tension: needs effects.two_phase = true")


#: ``scene.case`` → the ``params`` its diagnostics need.
CASE_PARAMS = {
    "gaussian-hill": ("x0", "y0", "sigma", "kappa"),
    "dam-break": ("a", "n2", "g"),
    "static-drop": ("R",),
}
#: ``scene.case`` → the ``scene.physics`` whose solution its diagnostics measure.
CASE_PHYSICS = {
    "zalesak": "transport",
    "gaussian-hill": "transport",
    "dam-break": "flow",
    "rising-bubble": "flow",
    "static-drop": "flow",
}


def _check_case(s: dict[str, dict[str, Any]], params: Mapping[str, float]) -> None:
    """What the built-in case diagnostics named by ``scene.case`` need."""
    case = s["scene"]["case"]
    physics = CASE_PHYSICS.get(case, s["scene"]["physics"])
    if physics != s["scene"]["physics"]:
        raise SceneError(f"scene.case: {case!r} needs scene.physics = {physics!r}")
    missing = [k for k in CASE_PARAMS.get(case, ()) if k not in params]
    if missing:
        raise SceneError(f"params.{missing[0]}: required by scene.case = {case!r}")
    if case == "zalesak":
        if s["transport"]["exact"] is None:
            raise SceneError("transport.exact: required by scene.case = 'zalesak'")
        if s["mesh"]["kind"] in ("interval", "box"):
            raise SceneError("scene.case: 'zalesak' needs a 2D mesh")
    if case in ("dam-break", "rising-bubble", "static-drop") and not s["effects"]["two_phase"]:
        raise SceneError(f"scene.case: {case!r} needs effects.two_phase = true")


def _check_expressions(scene: Scene) -> None:
    """Compile every expression now, so that bad ones are refused by ``check``."""
    gdim = scene.gdim
    structured = scene.mesh.kind in _DIMS

    def evaluated(*exprs: Expression) -> None:
        """Evaluate the constant ones (``9.0**9**9`` overflows)."""
        for e in exprs:
            if e.constant:
                e.value()

    try:
        if scene.physics == "flow":
            fl = scene.flow
            for k in ("velocity_scale", "time_factor", "max_speed"):
                e = scene.expr("flow", k)
                if e.constant and not math.isfinite(e.value()):
                    raise SceneError(f"flow.{k}: must be finite, got {e.text!r}")
            sigma = scene.expr("flow", "surface_tension")
            if not sigma.constant:
                raise SceneError(
                    f"flow.surface_tension: expected a constant (of params), got {sigma.text!r}"
                )
            try:
                sv = sigma.value()
            except ArithmeticError as exc:
                raise SceneError(f"flow.surface_tension: cannot be evaluated ({exc})") from None
            if not math.isfinite(sv) or sv < 0.0:
                raise SceneError(f"flow.surface_tension: must be finite and >= 0, got {sv:g}")
            for k in ("initial_velocity", "inflow_velocity", "exact_velocity"):
                v = getattr(fl, k)
                if v is not None:
                    evaluated(*scene.vector_expr("flow", k, gdim if structured else len(v)))
            if fl.exact_pressure is not None:
                evaluated(scene.expr("flow", "exact_pressure"))
            for name, ph in scene.phases.items():
                if ph.region is not None:
                    evaluated(Expression(ph.region, scene.params, f"phases.{name}.region"))
            vs = scene.expr("flow", "velocity_scale")
            if scene.time.courant is not None and fl.initial_velocity is None:
                if not vs.constant or vs.value() <= 0:
                    raise SceneError(
                        "flow.velocity_scale: time.courant on a fluid at rest needs a constant "
                        "velocity_scale > 0 (or give time.dt)"
                    )
        tr = scene.transport
        for k in scene.key_order["transport"]:
            v = getattr(tr, k)
            if v is None or k == "field":
                continue
            if isinstance(v, tuple):
                evaluated(*scene.vector_expr("transport", k, gdim if structured else len(v)))
            else:
                e = scene.expr("transport", k)
                evaluated(e)
                if k == "kappa" and e.constant and e.value() < 0:
                    raise SceneError(f"transport.kappa: must be >= 0, got {e.value():g}")
        if scene.physics == "transport" and scene.effects.advection:
            vel = scene.vector_expr(
                "transport", "velocity", gdim if structured else len(tr.velocity)
            )
            if scene.time.courant is not None and all(e.constant and e.value() == 0 for e in vel):
                raise SceneError(
                    "time.courant: the velocity is zero at t = 0; give time.dt instead"
                )
    except ExpressionError as exc:
        raise SceneError(str(exc)) from None


def _find_mesh_file(name: str, base_dir: Path) -> Path:
    p = Path(name)
    cands = [p] if p.is_absolute() else [base_dir / p, Path.cwd() / p] + [d / p for d in MESH_DIRS]
    for c in cands:
        if c.is_file():
            return c.resolve()
    raise SceneError(
        f"mesh.file: {name}: no such file (looked in {', '.join(str(c.parent) for c in cands)})"
    )


def toml_value(v: Any) -> str:
    """One value as TOML text (array, string, number, boolean).

    Raises
    ------
    TypeError
        For any other type (a table, ``None``).
    """
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise TypeError(type(v))


def dump_toml(data: Mapping[str, Any]) -> str:
    """Write a (nested) dict as TOML text (tables, arrays, strings, numbers, booleans)."""
    lines: list[str] = []

    def table(prefix: str, d: Mapping[str, Any]) -> None:
        scalars = {k: v for k, v in d.items() if not isinstance(v, dict) and v is not None}
        subs = {k: v for k, v in d.items() if isinstance(v, dict)}
        if prefix and (scalars or not subs):
            lines.append(f"[{prefix}]")
        for k, v in scalars.items():
            lines.append(f"{k} = {toml_value(v)}")
        if scalars:
            lines.append("")
        for k, v in subs.items():
            table(f"{prefix}.{k}" if prefix else k, v)

    table("", data)
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    print(schema_markdown(), end="")
