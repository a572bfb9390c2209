"""The form compiler's cache: a second process compiles no form the first one compiled."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pfem2x.compat import MPI

#: two forms on one mesh, compiled in this order (the second after the first's compile)
SCRIPT = """
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


def _compiled(cache: Path) -> set[str]:
    return {p.name for p in cache.rglob("libffcx_forms_*.c")}


def test_a_second_process_compiles_no_form_again(tmp_path):
    """FFCx 0.5 changed the mesh's coordinate element when it compiled a form, so the
    forms made after a compile had other cache keys than in a process that found
    everything cached, and each new run compiled one form again. The later processes
    hash strings with other seeds (a key must not depend on Python's hash seed)."""
    if MPI.COMM_WORLD.size > 1:
        return  # (a serial property: each rank would run the same processes)
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).parents[1]), env.get("PYTHONPATH", "")])
    env.pop("OMPI_COMM_WORLD_SIZE", None)
    run = [sys.executable, "-c", SCRIPT]
    first: set[str] = set()
    for seed in ("1", "6", "11"):
        env["PYTHONHASHSEED"] = seed
        subprocess.run(run, env=env, check=True, capture_output=True, timeout=300)
        if not first:
            first = _compiled(tmp_path / "cache")
            assert len(first) == 2, f"the first process compiled {sorted(first)}"
        again = _compiled(tmp_path / "cache") - first
        assert not again, f"a later process compiled {sorted(again)}; the first {sorted(first)}"
