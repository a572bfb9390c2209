"""What a new process imports: no ``pkg_resources`` for DOLFINx's versions."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pfem2x.compat import MPI

SCRIPT = """
import sys
import pfem2x.compat
import ufl, ffcx
assert "pkg_resources" not in sys.modules, "pkg_resources was imported"
versions = (ufl.__version__, ffcx.__version__)
import importlib.metadata as md
names = {"ufl": ("fenics-ufl", "ufl"), "ffcx": ("fenics-ffcx", "ffcx")}
for mod, v in zip(("ufl", "ffcx"), versions):
    found = []
    for name in names[mod]:
        try:
            found.append(md.version(name))
        except md.PackageNotFoundError:
            pass
    assert v in found, (mod, v, found)
import importlib.util
if importlib.util.find_spec("pkg_resources") is not None:  # (setuptools installed)
    import pkg_resources  # the real module afterwards
    assert hasattr(pkg_resources, "working_set"), pkg_resources
print("ok")
"""


def test_dolfinx_import_reads_versions_without_pkg_resources():
    """DOLFINx 0.5.2's UFL and FFCx read their versions through ``pkg_resources``, whose
    import scans every installed distribution; pfem2x.compat gives them the same
    versions from ``importlib.metadata``, and a later ``import pkg_resources`` still
    imports the real module."""
    if MPI.COMM_WORLD.size > 1:
        return  # (a serial property of a new process)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parents[1]), env.get("PYTHONPATH", "")])
    env.pop("OMPI_COMM_WORLD_SIZE", None)
    r = subprocess.run(
        [sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
