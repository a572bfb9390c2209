"""The kernels compiled ahead of time: the same types as numba's dispatch, the same
results as its JIT, numba's JIT for anything else."""

import csv
import json
import os
import subprocess
import sys
from collections import namedtuple

import numpy as np
import pytest

from pfem2x import aot, jit

Pair = namedtuple("Pair", ["a", "b"])


def _values():
    """Arguments of every kind the kernels take, and their near misses."""
    a = np.zeros((4, 3))
    ro = np.zeros(5, dtype=np.int32)
    ro.flags.writeable = False
    return [
        a, a[:, 0], a[:, :2], np.asfortranarray(a), np.zeros((4, 3), dtype=np.float32),
        np.zeros(4, dtype=np.int64), np.zeros(4, dtype=np.int32), ro, np.zeros((2, 2, 2)),
        np.zeros(3, dtype=bool), np.zeros(3, dtype=np.int8), np.zeros((3, 1)),
        1, -(2**63), 2**63, True, np.bool_(False), 1.5, np.float64(2.0), np.float32(2.0),
        np.int64(3), np.int32(3), np.uint64(3),
        (a, a), (a, np.zeros(4, dtype=np.int32)), Pair(a, 1), Pair(1.0, a), (a,),
    ]  # fmt: skip


def test_the_argument_checks_accept_what_numba_types_alike():
    """A compiled specialisation runs exactly for the arguments numba would type as it."""
    import numba

    values = _values()
    types = [numba.typeof(v) for v in values]
    for t in types:
        try:
            check = aot._check(jit._aot_spec(t))
        except ValueError:
            continue
        for u, w in zip(types, values, strict=True):
            assert check(w) == (u == t), (t, u)


def test_a_compiled_kernel_takes_numba_for_other_types():
    """A call the compiled module has no specialisation for runs through numba's JIT,
    which the process imports only then, and the kernel is recorded. (DOLFINx 0.11's
    FFCx imports numba itself, for its own helpers.)"""
    if not aot.is_current():
        pytest.skip("no current compiled module (make setup builds it)")
    code = (
        "import sys, numpy as np\n"
        "from pfem2x import aot\n"
        "from pfem2x.particles import _kernels as K\n"
        "by_dolfinx = 'numba' in sys.modules\n"
        "assert type(K.is_identity) is aot.Kernel and aot.active()\n"
        "assert K.is_identity(np.arange(4)) and not K.is_identity(np.arange(4)[::-1].copy())\n"
        "assert aot.jit_kernels() == [] and ('numba' in sys.modules) == by_dolfinx\n"
        "assert K.is_identity(np.arange(4, dtype=np.int32))\n"  # (compiled for int64 only)
        "assert not K.is_identity(np.arange(8)[::-2])\n"  # (not contiguous)
        "assert 'numba' in sys.modules and aot.jit_kernels() == ['is_identity']\n"
        "assert type(K.is_identity) is aot.Kernel\n"  # (the module keeps the compiled kernels)
        "src, out = np.arange(6.0).reshape(3, 2), np.zeros((3, 2))\n"
        "K.gather_rows(src, np.array([2, 0, 1]), out)\n"
        "assert out[0, 0] == 4.0 and aot.jit_kernels() == ['is_identity']\n"
        # numba compiles a kernel that calls another module's kernel (F layout: new)
        "from pfem2x.physics.flow import _kernels as F\n"
        "rng = np.random.default_rng(1)\n"
        "c, p = rng.random((40, 2)), rng.random((30, 2))\n"
        "a = F.pairs_within_kernel(c, p, 0.2)\n"
        "b = F.pairs_within_kernel(np.asfortranarray(c), p, 0.2)\n"
        "assert all(np.array_equal(x, y) for x, y in zip(a, b)) and len(a[0]) > 0\n"
        "assert aot.jit_kernels() == ['is_identity', 'pairs_within_kernel']\n"
        "assert type(F.counting_sort) is aot.Kernel\n"
    )
    env = {k: v for k, v in os.environ.items() if k != aot.ENV}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_the_environment_and_a_stale_module_take_numba(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert not aot.is_current()  # nothing there
    folder = aot.cache_dir()
    folder.mkdir()
    (folder / "x.so").write_bytes(b"")
    manifest = {"file": "x.so", "hash": aot.source_hash(), "kernels": {}}
    (folder / aot.MANIFEST).write_text(json.dumps(manifest))
    assert aot.is_current()
    manifest["hash"] = "0" * 40  # built from other sources (or numba, or Python)
    (folder / aot.MANIFEST).write_text(json.dumps(manifest))
    assert not aot.is_current()
    code = "from pfem2x import aot; import pfem2x.particles._kernels; print(aot.active())"
    env = {**os.environ, aot.ENV: "numba"}
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.strip() == "False", r.stderr


def _run(tmp_path, name, env):
    out = tmp_path / name
    cmd = [sys.executable, "-m", "pfem2x", "run", "rayleigh-taylor", "--variant", "small",
           "--set", "output.png=false", "--out", str(out), "--quiet"]  # fmt: skip
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with open(out / "diagnostics.csv") as f:
        rows = [{k: v for k, v in row.items() if k != "wall_step"} for row in csv.DictReader(f)]
    return json.loads((out / "summary.json").read_text()), rows


def test_a_run_on_the_compiled_kernels_equals_numbas_bit_for_bit(tmp_path):
    if not aot.is_current():
        pytest.skip("no current compiled module (make setup builds it)")
    env = {k: v for k, v in os.environ.items() if k != aot.ENV}
    s_aot, rows_aot = _run(tmp_path, "aot", env)
    s_jit, rows_jit = _run(tmp_path, "jit", {**env, aot.ENV: "numba"})
    assert (s_aot["kernels"], s_aot["kernels_jit"]) == ("ahead of time", [])
    assert s_jit["kernels"] == "numba"
    assert rows_aot == rows_jit
    assert s_aot["metrics"] == s_jit["metrics"]
