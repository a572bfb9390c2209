"""Which physics has which effect, and which frame reads which numerical switch.

:data:`PHYSICS_EFFECTS` (``effects.KEY = true`` of another physics is bad input) and
:data:`FRAME_KEYS` (a ``[frames.FRAME]`` table may set only its frame's keys; the scene
reference's table of numerical switches by frame), besides :data:`FLOW_COMMON_KEYS`,
the ``[flow]`` keys of both flow frames.
"""

from __future__ import annotations

from pfem2x.scene_schema import FLOW_SIDES

__all__ = ["FLOW_COMMON_KEYS", "FRAME_KEYS", "PHYSICS_EFFECTS"]

#: The effects each physics has (``effects.KEY = true`` of another physics is refused).
PHYSICS_EFFECTS: dict[str, tuple[str, ...]] = {
    "transport": ("advection", "diffusion", "source", "reaction"),
    "flow": ("gravity", "viscosity", "two_phase", "surface_tension"),
}

#: ``[flow]`` keys read by both flow frames.
FLOW_COMMON_KEYS = (
    *(f"flow.{k}" for k in ("gravity", "velocity_scale", "initial_velocity", "time_factor")),
    "flow.inflow_velocity",
    "flow.exact_velocity",
    "flow.exact_pressure",
    "flow.walls",
    *(f"flow.{s}" for s in FLOW_SIDES),
    *(f"flow.{k}" for k in ("max_speed", "pressure_step", "correction", "rtol")),
    "flow.divergence_rtol",
    "flow.divergence_preconditioner",
    "flow.surface_tension",
    "flow.capillary_increment",
    "flow.capillary_damping",
)
_PARTICLES = (
    "method.particles_per_cell",
    "method.min_particles_per_cell",
    "method.max_particles_per_cell",
    "method.projection",
    "method.substep_courant",
    "method.substep_gradient",
    "method.seed",
)
#: Which frame reads which numerical switch: physics → frame → ``section.key``
#: (besides :data:`FLOW_COMMON_KEYS` for flow).
FRAME_KEYS: dict[str, dict[str, tuple[str, ...]]] = {
    "transport": {
        "eulerian": ("method.theta", "method.supg", "method.preconditioner"),
        "characteristic": (
            "method.theta",
            "method.source_integration",
            "method.substep_courant",
            "method.preconditioner",
        ),
        "lagrangian": (
            *_PARTICLES,
            "method.theta",
            "method.source_integration",
            "method.preconditioner",
        ),
    },
    "flow": {
        "eulerian": (
            "method.supg",
            "method.preconditioner",
            "flow.interface_width",
            "flow.reinit_every",
            "flow.volume_correction",
            "flow.quadrature_degree",
        ),
        "lagrangian": (
            *_PARTICLES,
            "method.preconditioner",
            "flow.pic_fraction",
            "flow.pic_fraction_light",
            "flow.new_particle_velocity",
            "flow.light_source",
            "flow.mass_weighted",
            "flow.affine",
            "flow.density",
            "flow.particle_redistance",
            "flow.extra_pass",
            "flow.pass_splits",
            "flow.predictor",
            "flow.predictor_substeps",
            "flow.predictor_particles",
            "flow.predictor_rtol",
            "flow.predictor_divergence_rtol",
            "flow.viscous_step",
            "flow.explicit_pressure",
            "flow.pass_pressure",
        ),
    },
}
