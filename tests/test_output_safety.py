"""Output folders: --overwrite replaces only pfem2x folders; default folders stay inside."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pfem2x import cli
from pfem2x.output import MARKER, check_default_out, removable
from pfem2x.runner import Simulation
from pfem2x.scene import SceneError, load_scene
from pfem2x.study import STUDY_MARKER, StudyError, run_study

QUICK = ["output.png=false", "output.fields=false", "output.csv=false"]


def one_error_line(err: str, *names: str) -> None:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    for name in names:
        assert name in lines[0], (name, lines[0])


def test_overwrite_refuses_a_foreign_folder(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    res = subprocess.run(
        [sys.executable, "-m", "pfem2x", "run", "gaussian-hill", "--variant", "small"]
        + ["--out", str(out), "--overwrite", "--quiet"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert res.returncode == 2
    one_error_line(res.stderr, str(out), MARKER)
    assert (out / "thesis.tex").read_text() == "years of work"
    assert sorted(p.name for p in out.iterdir()) == ["thesis.tex"]


def test_overwrite_replaces_a_run_folder(tmp_path):
    scene = load_scene("gaussian-hill", QUICK, "small")
    out = tmp_path / "run"
    assert Simulation(scene, out, quiet=True).run().status == "ok"
    assert (out / MARKER).is_file() and (out / "summary.json").is_file()
    (out / "stale.txt").write_text("from the first run")
    with pytest.raises(SceneError, match="--overwrite"):
        Simulation(scene, out, quiet=True).run()
    assert Simulation(scene, out, quiet=True, overwrite=True).run().status == "ok"
    assert not (out / "stale.txt").exists() and (out / MARKER).is_file()


def test_never_replaces_the_current_folder_or_its_parents(tmp_path, monkeypatch):
    here = tmp_path / "a" / "b"
    here.mkdir(parents=True)
    monkeypatch.chdir(here)
    for folder in (here, tmp_path / "a", tmp_path):
        (folder / MARKER).write_text("")
        assert "refusing" in removable(folder)
    assert "refusing" in removable(Path("/"))
    assert "refusing" in removable(Path.home())
    other = tmp_path / "c"
    other.mkdir()
    (other / MARKER).write_text("")
    assert removable(other) == ""


def test_default_output_folder_stays_inside_runs(tmp_path, monkeypatch, capsys):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    argv = ["run", "gaussian-hill", "--variant", "small", "--quiet"]
    code = cli.main(argv + ["--set", 'scene.name="../../escape"'])
    assert code == 2
    one_error_line(capsys.readouterr().err, "scene.name")
    assert not (tmp_path / "escape").exists() and not (work / "runs").exists()
    # the runner's own check, whatever the scene validation lets through
    for name in ("../escape", "..", ".", "x/../../escape", "/tmp/escape"):
        with pytest.raises(SceneError, match="scene.name"):
            check_default_out(Path("runs") / name, "runs")
    check_default_out(Path("runs") / "gaussian-hill", "runs")


def test_study_refuses_a_folder_with_foreign_files(tmp_path):
    out = tmp_path / "mine"
    (out / "variants").mkdir(parents=True)
    (out / "thesis.tex").write_text("years of work")
    with pytest.raises(StudyError, match=STUDY_MARKER):
        run_study("gaussian-hill", ["time.courant=2,5"], variant="small", out=out, quiet=True)
    assert sorted(p.name for p in out.iterdir()) == ["thesis.tex", "variants"]


def test_study_default_folder_stays_inside_studies(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError, match="scene.name"):
        run_study(
            "gaussian-hill",
            ["time.courant=2,5"],
            sets=['scene.name="../escape"'],
            variant="small",
            quiet=True,
        )
    assert not (tmp_path / "escape").exists()


def test_output_files_honour_the_umask(tmp_path):
    """Files written atomically (summary, scene, checkpoint) get the mode of ordinary ones."""
    from pfem2x.io import atomic_write_text

    old = os.umask(0o027)
    try:
        atomic_write_text(tmp_path / "a.txt", "x")
        assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o640
        scene = load_scene(
            "gaussian-hill", QUICK + ["output.csv=true", "output.checkpoint_every=2"], "small"
        )
        out = tmp_path / "run"
        assert Simulation(scene, out, quiet=True).run().status == "ok"
    finally:
        os.umask(old)
    modes = {str(p.relative_to(out)): p.stat().st_mode & 0o777 for p in out.rglob("*")}
    for name in ("summary.json", "scene.toml", "diagnostics.csv", "checkpoint/meta.json"):
        assert name in modes, name
    assert modes == {k: (0o750 if (out / k).is_dir() else 0o640) for k in modes}
