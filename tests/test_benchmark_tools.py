"""The measuring tools of ``benchmarks/``: they run on the current code."""

import importlib.util
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _module(name: str = "move_replay"):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_saved_moves_replay_to_the_same_end_state(tmp_path, capsys):
    """Moves 2-3 of Rayleigh-Taylor's small variant: saved, replayed twice, equal to the bit.

    The second replay compares its end states with the first's; a move that did not
    move (or a state written wrongly) would show in the sub-step counts or the comparison.
    """
    mod = _module()
    moves = tmp_path / "moves.pkl"
    assert mod.main(["save", "rayleigh-taylor", str(moves), "--variant", "small",
                     "--first", "2", "--count", "2"]) == 0  # fmt: skip
    state = tmp_path / "a.npz"
    assert mod.main(["replay", str(moves), "--repeat", "1", "--state", str(state)]) == 0
    rows, same = mod.replay(moves, 1, None, state)
    out = capsys.readouterr().out
    assert same is True and "to the bit: yes" in out
    assert len(rows) == 2 and all(r["substeps"] >= r["particles"] > 0 for r in rows)
    assert mod.main(["replay", str(moves), "--repeat", "1", "--compare", str(state)]) == 0
    # end states that differ: "NO" and exit status 1
    ends = dict(np.load(state))
    ends["0_x"] = ends["0_x"] + 1e-12
    other = tmp_path / "other.npz"
    np.savez(other, **ends)
    assert mod.main(["replay", str(moves), "--repeat", "1", "--compare", str(other)]) == 1
    assert "to the bit: NO" in capsys.readouterr().out
    # bad input: one error line, exit 2
    assert mod.main(["replay", str(tmp_path / "none.pkl")]) == 2
    assert "error:" in capsys.readouterr().err
    assert mod.main(["save", "rayleigh-taylor", str(moves), "--count", "0"]) == 2
    garbage = tmp_path / "garbage.pkl"
    garbage.write_bytes(b"not a pickle")
    assert mod.main(["replay", str(garbage)]) == 2
    assert "error:" in capsys.readouterr().err


def test_solver_profile_times_every_kind_of_solve(monkeypatch, capsys):
    """``benchmarks/solver_profile.py`` on Rayleigh-Taylor's small variant: every solve kind.

    Its wrappers pass every argument of the solves on (a solve with its own tolerance
    included); the originals are restored after the test. ``--time`` times named
    functions (a package's name, a class's method) and puts them back after the run;
    a name that does not resolve is one error line and exit 2.
    """
    from pfem2x import fem
    from pfem2x import particles as P
    from pfem2x.particles.cloud import Cloud
    from pfem2x.physics.flow import projection

    monkeypatch.setattr(fem.LinearSolver, "solve", fem.LinearSolver.solve)
    monkeypatch.setattr(
        projection._DiscreteProjection, "solve", projection._DiscreteProjection.solve
    )
    mod = _module("solver_profile")
    project, sort = P.project_fields, Cloud.__dict__["sort_by_cell"]
    times = [
        "--time",
        "pfem2x.particles:project_fields",
        "--time",
        "pfem2x.particles.cloud:Cloud.sort_by_cell",
    ]
    assert mod.main(["rayleigh-taylor", "--variant", "small", *times]) == 0
    out = capsys.readouterr().out
    assert "cg/jacobi" in out and "discrete/gmres" in out and "solve timer" in out
    rows = {r.split("|")[1].strip(): r.split("|")[2:4] for r in out.splitlines() if ":" in r}
    for name in ("pfem2x.particles:project_fields", "pfem2x.particles.cloud:Cloud.sort_by_cell"):
        calls, secs = (float(v) for v in rows[name])
        assert calls > 10 and secs > 0.0
    assert P.project_fields is project and Cloud.__dict__["sort_by_cell"] is sort
    for bad in ("pfem2x.particles:no_such", "no_such_module:f", "pfem2x.particles"):
        assert mod.main(["rayleigh-taylor", "--variant", "small", "--time", bad]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: --time") and err.count("\n") == 1
    assert P.project_fields is project


def test_picture_benchmark_draws_six_snapshots_per_checkout(tmp_path, capsys):
    """``benchmarks/picture.py``: a fresh process per run, the medians per checkout; a
    folder without pfem2x is one ``error:`` line and exit 2."""
    import json

    mod = _module("picture")
    out = tmp_path / "p.json"
    args = ["--checkout", f"now={ROOT}", "--cells", "8", "32", "--repeat", "1", "--json", str(out)]
    assert mod.main(args) == 0
    runs = json.loads(out.read_text())["runs"]["now"]
    assert len(runs) == 1 and 0 < runs[0]["next"] <= runs[0]["six"]
    assert "| now | 1 |" in capsys.readouterr().out
    assert mod.main(["--checkout", f"x={tmp_path}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --checkout")
