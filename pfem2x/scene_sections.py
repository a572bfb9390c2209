"""Typed, frozen sections of a validated scene.

Each ``[section]`` of a scene becomes a frozen dataclass whose fields are the
section's keys in schema order (defaults filled in, lists stored as tuples),
e.g. ``scene.time.t_end`` or ``scene.phases["heavy"].density``.

A section is also a read-only mapping, for code written against the plain
dicts that scenes used to be: ``section["key"]`` returns the value with tuples
turned back into lists, and iteration yields the keys in schema order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Self

__all__ = [
    "EffectsSection",
    "FlowSection",
    "MeshSection",
    "MethodSection",
    "OutputSection",
    "PhaseSection",
    "SceneSection",
    "Section",
    "TimeSection",
    "TransportSection",
    "freeze",
    "thaw",
]

#: An expression string or a number (compiled by :mod:`pfem2x.expr`).
ExprText = str | float | int


def freeze(v: Any) -> Any:
    """``v`` with every list (nested too) turned into a tuple."""
    if isinstance(v, list | tuple):
        return tuple(freeze(x) for x in v)
    return v


def thaw(v: Any) -> Any:
    """``v`` with every tuple (nested too) turned into a list (a fresh copy)."""
    if isinstance(v, list | tuple):
        return [thaw(x) for x in v]
    return v


class Section(Mapping[str, Any]):
    """Base of the section dataclasses: read-only ``section["key"]`` access.

    Fields named in ``_derived`` are computed by validation and are not scene keys:
    they are attributes only (not in the mapping view, not written back to TOML).
    """

    _derived: ClassVar[tuple[str, ...]] = ()

    def _keys(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(self) if f.name not in self._derived)

    def __getitem__(self, key: str) -> Any:
        if key not in self._keys():
            raise KeyError(key)
        return thaw(getattr(self, key))

    def __iter__(self) -> Iterator[str]:
        return iter(self._keys())

    def __len__(self) -> int:
        return len(self._keys())

    def as_dict(self) -> dict[str, Any]:
        """The scene keys and their values as a plain dict (lists, not tuples)."""
        return {k: self[k] for k in self}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], **derived: Any) -> Self:
        """A section from checked values (lists are frozen into tuples)."""
        return cls(**{k: freeze(v) for k, v in d.items()}, **derived)


@dataclass(frozen=True)
class SceneSection(Section):
    """``[scene]``."""

    name: str
    description: str
    physics: str
    case: str


@dataclass(frozen=True)
class MeshSection(Section):
    """``[mesh]``; ``file`` is the resolved path, ``num_cells`` the cell count (structured)."""

    kind: str
    bounds: tuple[tuple[float, ...], tuple[float, ...]] | None
    cells: tuple[int, ...] | None
    diagonal: str
    file: str | None
    periodic: tuple[bool, ...] | None
    partition: str | tuple[int, int] | None
    num_cells: int | None = None

    _derived: ClassVar[tuple[str, ...]] = ("num_cells",)


@dataclass(frozen=True)
class EffectsSection(Section):
    """``[effects]``: which terms are active."""

    advection: bool
    diffusion: bool
    source: bool
    reaction: bool
    gravity: bool
    viscosity: bool
    two_phase: bool
    surface_tension: bool


@dataclass(frozen=True)
class TimeSection(Section):
    """``[time]``: exactly one of ``dt`` and ``courant`` is set."""

    t_end: float
    dt: float | None
    courant: float | None
    max_steps: int
    adaptive: bool
    max_courant: float | None
    max_energy_growth: float
    max_growth: float


@dataclass(frozen=True)
class MethodSection(Section):
    """``[method]``: the frame and its numerical switches."""

    frame: str
    particles_per_cell: int
    min_particles_per_cell: int
    max_particles_per_cell: int
    projection: str
    substep_courant: float
    substep_gradient: float
    source_integration: str
    theta: float
    supg: bool
    preconditioner: str
    seed: int


@dataclass(frozen=True)
class OutputSection(Section):
    """``[output]``."""

    every: float
    fields: bool
    particles: bool
    particle_precision: str
    png: bool
    png_times: tuple[float, ...] | None
    csv: bool
    checkpoint_every: int


@dataclass(frozen=True)
class TransportSection(Section):
    """``[transport]``: expressions as given (compile with ``Scene.expr``)."""

    field: str
    velocity: tuple[ExprText, ...] | None
    kappa: ExprText
    source: ExprText
    reaction: ExprText
    initial: ExprText
    exact: ExprText | None
    boundary_value: ExprText | None


@dataclass(frozen=True)
class FlowSection(Section):
    """``[flow]``: expressions as given (compile with ``Scene.expr``)."""

    gravity: tuple[float, ...] | None
    velocity_scale: ExprText
    initial_velocity: tuple[ExprText, ...] | None
    exact_velocity: tuple[ExprText, ...] | None
    exact_pressure: ExprText | None
    time_factor: ExprText
    walls: str
    left: str | None
    right: str | None
    bottom: str | None
    top: str | None
    front: str | None
    back: str | None
    inflow_velocity: tuple[ExprText, ...] | None
    interface_width: float
    reinit_every: int
    volume_correction: bool
    max_speed: ExprText
    extra_pass: bool
    pass_splits: int
    predictor: str
    predictor_substeps: float
    predictor_particles: float
    predictor_rtol: float
    predictor_divergence_rtol: float
    viscous_step: str
    pic_fraction: float
    pic_fraction_light: float
    new_particle_velocity: str
    light_source: str
    mass_weighted: bool
    affine: bool
    density: str
    particle_redistance: bool
    pass_pressure: str
    explicit_pressure: str
    pressure_step: str
    correction: str
    surface_tension: ExprText
    capillary_increment: bool
    capillary_damping: str
    rtol: float
    divergence_rtol: float
    divergence_preconditioner: str
    quadrature_degree: int

    def side(self, name: str) -> str:
        """The boundary kind of box side ``name`` (``walls`` unless the side is named)."""
        return getattr(self, name) or self.walls


@dataclass(frozen=True)
class PhaseSection(Section):
    """``[phases.NAME]``; ``region`` is ``None`` for the phase that fills the rest.

    The mapping view has the keys in the order the scene gave them (``viscosity``
    last when it was not given) and no ``region`` key when there is none.
    """

    name: str
    density: float
    viscosity: float
    region: ExprText | None
    given_order: tuple[str, ...] = ("density", "viscosity", "region")

    _derived: ClassVar[tuple[str, ...]] = ("name", "given_order")

    def _keys(self) -> tuple[str, ...]:
        return tuple(k for k in self.given_order if k != "region" or self.region is not None)
