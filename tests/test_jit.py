"""The particle kernels' warm-up: the cold-cache check and the announcement."""

import itertools
import os
import time
from pathlib import Path

import pytest

from pfem2x import jit


def test_cold_cache_check_follows_marker_and_index_files(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    folder = jit.cache_dir()
    assert folder.parent == tmp_path
    assert jit.is_cold()  # nothing there
    folder.mkdir()
    src = jit.KERNELS.stat().st_mtime
    index = [folder / f"_kernels.k{i}-1.{jit._TAG}.nbi" for i in range(2)]
    for p in index:
        p.write_bytes(b"")
    assert jit.is_cold()  # index files but no completed warm-up
    jit._mark_warm()
    assert (folder / jit.MARKER).read_text().split() == ["2", jit.numba_version()]
    assert not jit.is_cold()
    installed = jit.numba_version
    monkeypatch.setattr(jit, "numba_version", lambda: "0.0.0")  # numba changed since
    assert jit.is_cold()
    monkeypatch.setattr(jit, "numba_version", installed)
    assert not jit.is_cold()
    index[0].unlink()  # a cache file removed since
    assert jit.is_cold()
    index[0].write_bytes(b"")
    assert not jit.is_cold()
    os.utime(index[1], (src - 10, src - 10))  # an index older than the kernels' source
    assert jit.is_cold()
    os.utime(index[1], None)
    stale = folder / f"_kernels.old-9.{jit._TAG}.nbi"  # left by an earlier _kernels.py
    stale.write_bytes(b"")
    os.utime(stale, (src - 10, src - 10))
    assert not jit.is_cold()
    os.utime(folder / jit.MARKER, (src - 10, src - 10))  # a warm-up of older kernels
    assert jit.is_cold()
    # a warm-up by an older warm-up module (which may not have called every kernel)
    own = Path(jit.__file__).resolve().stat().st_mtime
    os.utime(folder / jit.MARKER, (own - 10, own - 10))
    assert jit.is_cold()


def test_warm_up_on_a_warm_cache_is_quiet_and_loads_nothing(monkeypatch):
    jit.warm_up()  # compiles if this checkout's cache is cold
    assert not jit.is_cold()

    def exercise():
        raise AssertionError("a warm cache is not exercised")

    monkeypatch.setattr(jit, "exercise_particles", exercise)
    said = []
    t0 = time.perf_counter()
    seconds = jit.warm_up(said.append)
    assert 0.0 <= seconds <= time.perf_counter() - t0
    assert said == []


def test_a_compile_after_a_warm_check_is_announced_once():
    """Should the cache check be wrong, the first kernel numba compiles says so."""
    import numba

    jit.warm_up()
    said = []
    jit.warm_up(said.append)

    @numba.njit
    def twice(x):
        return 2 * x

    @numba.njit
    def thrice(x):
        return 3 * x

    assert said == []
    assert twice(2) == 4 and thrice(2) == 6
    assert said == [jit.MESSAGE]
    assert twice(2.5) == 5.0  # (a second compile)
    assert said == [jit.MESSAGE]
    jit.warm_up(said.append)
    jit.warm_up(None)  # quiet again

    @numba.njit
    def once(x):
        return x

    assert once(1) == 1
    assert said == [jit.MESSAGE]


def test_warm_up_announces_a_cold_cache(monkeypatch):
    said = []
    monkeypatch.setattr(jit, "is_cold", lambda: True)
    monkeypatch.setattr(jit, "exercise_particles", lambda: None)
    monkeypatch.setattr(jit, "_mark_warm", lambda: None)
    jit.warm_up(said.append)
    assert said == [jit.MESSAGE]
    assert "compiling particle kernels" in jit.MESSAGE


def test_the_command_says_what_it_did(monkeypatch, capsys):
    """``python -m pfem2x.jit``: a warm cache is said to be warm (nothing compiled, and
    with ``--if-cold`` nothing said); a cold one is compiled and the seconds said; a
    compiled module that is not current is built."""
    from pfem2x import aot

    monkeypatch.setattr(aot, "is_current", lambda: True)
    monkeypatch.setattr(jit, "is_cold", lambda: False)
    assert jit.main([]) == 0
    assert "cache warm, nothing to compile" in capsys.readouterr().out
    assert jit.main(["--if-cold"]) == 0
    assert capsys.readouterr().out == ""
    monkeypatch.setattr(jit, "is_cold", lambda: True)
    monkeypatch.setattr(jit, "exercise_particles", lambda: None)
    monkeypatch.setattr(jit, "_mark_warm", lambda: None)
    assert jit.main([]) == 0
    out = capsys.readouterr()
    assert "particle kernels compiled in" in out.out and jit.MESSAGE in out.err
    assert "compiled ahead of time: current" in out.out
    monkeypatch.setattr(jit, "is_cold", lambda: False)
    monkeypatch.setattr(aot, "is_current", lambda: False)
    monkeypatch.setattr(jit, "build_ahead_of_time", lambda: (False, "no compiler"))
    assert jit.main(["--if-cold"]) == 0
    assert capsys.readouterr().out == "pfem2x: no compiler\n"


def test_the_package_is_byte_compiled_whatever_python_may_write(tmp_path, monkeypatch):
    """``compile_bytecode`` writes the ``.pyc`` of every module, also where Python itself
    would not (``PYTHONDONTWRITEBYTECODE``), and again after a module changes."""
    import importlib.util
    import os
    import sys

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    monkeypatch.setattr(sys, "dont_write_bytecode", True)
    (tmp_path / "sub").mkdir()
    for name in ("a.py", "sub/b.py"):
        (tmp_path / name).write_text("X = 1\n")
    assert jit.compile_bytecode(tmp_path)
    pyc = [tmp_path / importlib.util.cache_from_source(n) for n in ("a.py", "sub/b.py")]
    assert all(p.is_file() for p in pyc)
    before = pyc[0].stat().st_mtime_ns
    (tmp_path / "a.py").write_text("X = 2\n")
    os.utime(tmp_path / "a.py", ns=(before + 10**9, before + 10**9))
    assert jit.compile_bytecode(tmp_path)
    assert pyc[0].stat().st_mtime_ns != before, "a stale .pyc is written again"


@pytest.mark.slow
def test_after_the_warm_up_no_scene_run_compiles_a_kernel(tmp_path):
    """``python -m pfem2x.jit`` (``make setup``) compiles every kernel the scenes call,
    into numba's cache and ahead of time (no run falls back to numba's JIT)."""
    import json
    import subprocess
    import sys

    from pfem2x import aot

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "NUMBA_DEBUG_CACHE": "1"}
    env.pop(aot.ENV, None)
    r = subprocess.run(
        [sys.executable, "-m", "pfem2x.jit"], env=env, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stderr
    # (DOLFINx's forms need a C compiler too: the module is built wherever pfem2x runs)
    assert "kernels compiled ahead of time in" in r.stdout, r.stdout + r.stderr
    quiet = ["--set", "output.png=false", "--set", "output.fields=false"]
    runs = [
        ("rayleigh-taylor", "lagrangian"),  # the first pass's share, the cellwise operators
        ("dam-break", "lagrangian"),
        ("rising-bubble", "lagrangian"),  # the curvature's fits
        ("rising-bubble", "eulerian"),
    ]
    kinds = [("numba", {**env, aot.ENV: "numba"}), ("ahead of time", env)]
    for (scene, frame), (kind, run_env) in itertools.product(runs, kinds):
        out = tmp_path / f"{scene}-{frame}-{kind}"
        r = subprocess.run(
            [sys.executable, "-m", "pfem2x", "run", scene, "--variant", "small", *quiet,
             "--set", f'method.frame="{frame}"', "--out", str(out)],
            env=run_env, capture_output=True, text=True,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
        compiled = [ln for ln in (r.stdout + r.stderr).splitlines() if "index saved" in ln]
        assert not compiled, (scene, frame, kind, compiled)
        assert jit.MESSAGE not in r.stderr
        summary = json.loads((out / "summary.json").read_text())
        assert (summary["kernels"], summary["kernels_jit"]) == (kind, []), (scene, frame)
