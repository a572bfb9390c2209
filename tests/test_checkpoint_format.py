"""Checkpoints store the solvers' declared state; those of the earlier format resume or
give one error line naming what they lack.

``tests/data/checkpoint-v0`` holds two serial checkpoints (Rayleigh–Taylor on a
3 x 12 mesh, level-set and PFEM-2 frames, step 2 of 3) written by pfem2x before
the solvers declared their state (then every attribute was stored; the key
names ``function.NAME``, ``array.NAME``, ``json.NAME`` are the same) and before
the balanced two-phase gravity (so a resumed level-set run continues with other
numerics than those that wrote it, and the PFEM-2 one lacks a particle field).
"""

import json
import shutil
import tomllib
from pathlib import Path

import numpy as np
import pytest

from pfem2x import cli, compat, jit
from pfem2x.compat import MPI
from pfem2x.physics import solver_class
from pfem2x.physics.base import Solver
from pfem2x.runner import Simulation
from pfem2x.scene import validate

DATA = Path(__file__).parent / "data" / "checkpoint-v0"

serial_052 = pytest.mark.skipif(
    MPI.COMM_WORLD.size > 1 or compat.NEW_API,
    reason="serial checkpoints written with DOLFINx 0.5.2 (its dof numbering)",
)


def _copy(tmp_path: Path, frame: str) -> Path:
    run = tmp_path / "run"
    tmp_path.mkdir(parents=True, exist_ok=True)
    shutil.copytree(DATA / f"rt-{frame}", run)
    return run


@pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="one checkpoint file: serial")
@pytest.mark.parametrize("frame", ["eulerian", "lagrangian"])
def test_checkpoint_with_extra_entries_resumes_bit_identically(tmp_path, frame):
    """Entries that are not declared state (earlier versions stored every attribute) are
    ignored: a checkpoint written now, with such entries added, resumes bit-identically."""
    run = _copy(tmp_path, frame)
    raw = tomllib.loads((run / "scene.toml").read_text(encoding="utf-8"))
    raw["output"]["checkpoint_every"] = 2  # the last checkpoint (step 2 of 3) stays
    ra = Simulation(validate(raw), tmp_path / "part", quiet=True).run()
    npz = tmp_path / "part" / "checkpoint" / "rank0.npz"
    with np.load(npz) as f:
        data = {k: f[k] for k in f.files}
    data["array.setup_only"] = np.arange(5.0)  # as the earlier format stored set-up arrays
    data["json.iterations"] = np.array(json.dumps({"pressure": 3}))
    np.savez(npz, **data)
    rb = Simulation.resume(tmp_path / "part", quiet=True).run()
    assert rb.status == "ok" and rb.summary["resumed_at_step"] == 2
    assert rb.summary["steps"] == ra.summary["steps"] == 3
    if not compat.NEW_API:  # Debian's DOLFINx 0.5.2: bit-identical
        assert rb.summary["metrics"] == ra.summary["metrics"]
        return
    # DOLFINx 0.11 (PyPI wheel): the resumed flow-lagrangian run's metrics depend on the
    # interpreter's hash seed when the form kernels come from FFCx's disk cache filled by
    # other processes (PYTHONHASHSEED 0-11: three outcomes, up to 8e-16 relative; with a
    # fresh cache every seed gives the uninterrupted run's bits). Round-off is asserted:
    # relative, and absolute for the metrics that are round-off themselves (the phase
    # volumes' relative changes, ~5e-16: 6.6e-16 against 4.4e-16 with two hash seeds)
    ma, mb = ra.summary["metrics"], rb.summary["metrics"]
    assert ma.keys() == mb.keys()
    for k, va in ma.items():
        a, b = np.asarray(va, dtype=float), np.asarray(mb[k], dtype=float)
        assert a.shape == b.shape, k
        assert np.all(np.abs(a - b) <= 1e-13 * np.abs(a) + 1e-15), k


@serial_052
def test_checkpoint_of_the_earlier_format_resumes_or_names_what_it_lacks(tmp_path, capsys):
    """The level-set checkpoint of the earlier format resumes; the PFEM-2 one lacks the
    particles' signed distance (added with the balanced gravity): one error line."""
    jit.warm_up()  # no compile notice on stderr
    rb = Simulation.resume(_copy(tmp_path / "e", "eulerian"), quiet=True).run()
    assert rb.status == "ok" and rb.summary["steps"] == 3
    run = _copy(tmp_path / "l", "lagrangian")
    assert cli.main(["run", "--resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    assert "dist" in err and "flow-lagrangian" in err


@serial_052
def test_checkpoint_without_a_declared_state_is_one_error_line(tmp_path, capsys):
    jit.warm_up()  # no compile notice on stderr
    run = _copy(tmp_path, "lagrangian")
    npz = run / "checkpoint" / "rank0.npz"
    with np.load(npz) as f:
        data = {k: f[k] for k in f.files if k != "function.u_hat"}
    np.savez(npz, **data)
    assert cli.main(["run", "--resume", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    assert "'u_hat'" in err and "flow-lagrangian" in err
    assert npz.is_file() and (run / "checkpoint" / "meta.json").is_file()  # nothing lost


def test_declared_state_is_all_a_checkpoint_stores():
    """Every solver declares its state; set-up data is not checkpoint state."""
    for physics, frame in [
        ("transport", "eulerian"),
        ("transport", "characteristic"),
        ("transport", "lagrangian"),
        ("flow", "eulerian"),
        ("flow", "lagrangian"),
    ]:
        names = solver_class(physics, frame).state_names()
        assert names[0] == "timings" and len(names) == len(set(names))
        assert not {"coords", "dofmap", "cell_xy", "scene", "domain"} & set(names)
    flow = solver_class("flow", "lagrangian").state_names()
    assert {"u", "p", "phase", "rho", "u_hat", "step_count", "volume0"} <= set(flow)


class _Toy(Solver):
    checkpoint_state = ("a", "b", "c")


class _Toy2(_Toy):
    checkpoint_state = ("d", "a")


def test_state_names_join_the_class_hierarchy_and_refuse_objects(tmp_path):
    assert _Toy2.state_names() == ["timings", "a", "b", "c", "d"]
    from pfem2x.mesh import build_mesh

    domain = build_mesh(MPI.COMM_WORLD, "rectangle", bounds=[[0, 0], [1, 1]], cells=[2, 2])
    toy = _Toy.__new__(_Toy)
    toy.domain, toy.comm, toy.timings = domain, domain.comm, {"solve": 1.0}
    toy.a, toy.b, toy.c = np.arange(3.0), None, {"n": 2}
    ck = toy.checkpoint()
    assert {"array.a", "json.c", "json.timings"} <= set(ck) and "json.b" not in ck
    assert json.loads(str(ck["json.c"])) == {"n": 2}
    toy.a[:] = 0.0
    toy.c = {}
    toy.restore_checkpoint(ck)
    assert np.array_equal(toy.a, np.arange(3.0)) and toy.c == {"n": 2}
    toy.b = object()  # not storable: a programming error, not silently skipped
    with pytest.raises(TypeError, match="_Toy.b"):
        toy.checkpoint()
