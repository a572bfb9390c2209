"""Particle layer: clouds, seeding, location, X-IVAS moves, projection, population, MPI.

Knows meshes and P1 functions only (no physics). Typical step::

    cloud = Cloud(domain, {"T": ()})
    seed_cells(cloud, 8, seed=1)
    interpolate(cloud, "T", T_h)                 # initial values
    advect(cloud, u_h, dt)                       # eq. (2.10), theta = 0
    project(cloud, "T", T_h)                     # particles -> P1
    add_increment(cloud, "T", dT_h)              # P1 increment -> particles
    rebalance(cloud, nmin=6, nmax=12)            # add/remove
"""

from pfem2x.particles.advect import advect, nodal_values
from pfem2x.particles.cloud import Cloud
from pfem2x.particles.locate import LocateStats, locate_points, relocate
from pfem2x.particles.migrate import find_owners
from pfem2x.particles.pmesh import ParticleMesh
from pfem2x.particles.population import PopulationStats, rebalance, seed_inflow
from pfem2x.particles.seeding import assign_ids, seed_cells
from pfem2x.particles.transfer import (
    ProjectionStats,
    add_increment,
    evaluate,
    interpolate,
    project,
    project_fields,
)

__all__ = [
    "Cloud",
    "LocateStats",
    "ParticleMesh",
    "PopulationStats",
    "ProjectionStats",
    "add_increment",
    "advect",
    "assign_ids",
    "evaluate",
    "find_owners",
    "interpolate",
    "locate_points",
    "nodal_values",
    "project",
    "project_fields",
    "rebalance",
    "relocate",
    "seed_cells",
    "seed_inflow",
]
