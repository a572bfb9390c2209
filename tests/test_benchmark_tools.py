"""The measuring tools of ``benchmarks/``: they run on the current code."""

import importlib.util
from pathlib import Path

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
    rows = mod.replay(moves, 1, None, state)
    out = capsys.readouterr().out
    assert "to the bit: yes" in out
    assert len(rows) == 2 and all(r["substeps"] >= r["particles"] > 0 for r in rows)
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
    included); the originals are restored after the test.
    """
    from pfem2x import fem
    from pfem2x.physics.flow import projection

    monkeypatch.setattr(fem.LinearSolver, "solve", fem.LinearSolver.solve)
    monkeypatch.setattr(
        projection._DiscreteProjection, "solve", projection._DiscreteProjection.solve
    )
    mod = _module("solver_profile")
    assert mod.main(["rayleigh-taylor", "--variant", "small"]) == 0
    out = capsys.readouterr().out
    assert "cg/jacobi" in out and "discrete/gmres" in out and "solve timer" in out
