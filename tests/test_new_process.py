"""What a new process does before its run: the forms it compiles, the modules it imports."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

#: two forms on one mesh, compiled in this order (the second after the first's compile)
FORMS = """
import ufl
from pfem2x import compat
from pfem2x.mesh import build_mesh

mesh = build_mesh(compat.MPI.COMM_SELF, "rectangle", [[0.0, 0.0], [1.0, 1.0]], [3, 3]).mesh
Q = compat.function_space(mesh, 1)
V = compat.function_space(mesh, 1, shape=(2,))
q, r, w = ufl.TrialFunction(Q), ufl.TestFunction(Q), ufl.TrialFunction(V)
compat.form(ufl.dot(ufl.grad(q), ufl.grad(r)) * 7.25 * ufl.dx)
compat.form(ufl.div(w) * r * 7.25 * ufl.dx)
"""

VERSIONS = """
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


def _python(script: str, **env: str) -> subprocess.CompletedProcess:
    """Run ``script`` in a new Python process with ``env`` added to this one's."""
    return subprocess.run(
        [sys.executable, "-c", script],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=300,
    )


def _compiled(cache: Path) -> set[str]:
    return {p.name for p in cache.rglob("libffcx_forms_*.c")}


def test_a_second_process_compiles_no_form_again(tmp_path):
    """FFCx 0.5 changed the mesh's coordinate element when it compiled a form, so the
    forms made after a compile had other cache keys than in a process that found
    everything cached, and each new run compiled one form again. The later processes
    hash strings with other seeds (a key must not depend on Python's hash seed)."""
    cache = tmp_path / "cache"
    first: set[str] = set()
    for seed in ("1", "6", "11"):
        r = _python(FORMS, XDG_CACHE_HOME=str(cache), PYTHONHASHSEED=seed)
        assert r.returncode == 0, r.stderr[-2000:]
        if not first:
            first = _compiled(cache)
            assert len(first) == 2, f"the first process compiled {sorted(first)}"
        again = _compiled(cache) - first
        assert not again, f"a later process compiled {sorted(again)}; the first {sorted(first)}"


def test_dolfinx_import_reads_versions_without_pkg_resources():
    """DOLFINx 0.5.2's UFL and FFCx read their versions through ``pkg_resources``, whose
    import scans every installed distribution; pfem2x.compat gives them the same
    versions from ``importlib.metadata``, and a later ``import pkg_resources`` still
    imports the real module."""
    r = _python(VERSIONS)
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]
