"""pfem2x: PFEM-2 (the Particle Finite Element Method, second generation) on FEniCSx/DOLFINx.

Modules, small and named by concept: :mod:`pfem2x.compat` (DOLFINx
versions), :mod:`pfem2x.mesh`, :mod:`pfem2x.scene`, :mod:`pfem2x.expr`,
:mod:`pfem2x.fem`, :mod:`pfem2x.io`, :mod:`pfem2x.runner`,
:mod:`pfem2x.particles` and :mod:`pfem2x.physics`.
"""

__version__ = "0.1.0"
