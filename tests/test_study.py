"""``pfem2x study``: tables and plots of a small product, resume, divergence, bad input.

Serial only; every study runs ``gaussian-hill --variant small`` without field or
PNG output so that each variant takes about a second.
"""

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pfem2x.study import (
    StudyError,
    pareto_front,
    parse_axis,
    parse_vary,
    run_study,
    split_values,
)
from pfem2x.study.report import fmt_value

QUICK = ["--variant", "small", "--set", "output.png=false", "--set", "output.fields=false"]
VARY = ["--vary", "time.courant=2,5", "--vary", "method.theta=0.5,1"]


def study(*args):
    return subprocess.run(
        [sys.executable, "-m", "pfem2x", "study", *args],
        capture_output=True,
        text=True,
        timeout=300,
    )


def summaries(out):
    return {p.parent.name: p.stat().st_mtime_ns for p in out.glob("variants/*/summary.json")}


@pytest.fixture(scope="module")
def two_by_two(tmp_path_factory):
    out = tmp_path_factory.mktemp("study") / "gh"
    res = study("gaussian-hill", *QUICK, *VARY, "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    return out


def test_outputs(two_by_two):
    out = two_by_two
    for name in ("study.csv", "study.json", "study.md", "error_vs_wall.png", "error_vs_dt.png"):
        assert (out / name).is_file(), name
        assert (out / name).stat().st_size > 0, name
    with open(out / "study.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 4
    for key in ("time.courant", "method.theta", "status", "exit_code", "wall_seconds"):
        assert key in rows[0], key
    for key in ("cpu_seconds", "steps", "peak_rss_mb", "frame", "pareto", "message"):
        assert key in rows[0], key
    assert {(r["time.courant"], r["method.theta"]) for r in rows} == {
        ("2", "0.5"),
        ("2", "1"),
        ("5", "0.5"),
        ("5", "1"),
    }
    assert all(r["status"] == "ok" and r["exit_code"] == "0" for r in rows)
    assert all(float(r["peak_rss_mb"]) > 10 for r in rows)
    assert all(r["frame"] == "eulerian" for r in rows)
    assert any(r["pareto"] == "true" for r in rows)
    data = json.loads((out / "study.json").read_text())
    assert data["keys"] == ["time.courant", "method.theta"]
    assert data["vary"] == {"time.courant": ["2", "5"], "method.theta": ["0.5", "1"]}
    assert len(data["rows"]) == 4
    metric = data["metric"]
    assert metric is not None
    assert all(isinstance(r[metric], float) for r in data["rows"])
    assert all(r["steps"] > 0 and r["wall_seconds"] > 0 for r in data["rows"])
    md = (out / "study.md").read_text()
    assert "| time.courant | method.theta |" in md
    assert md.count("| ok |") == 4


def test_resume(two_by_two):
    out = two_by_two
    before = summaries(out)
    assert len(before) == 4
    res = study("gaussian-hill", *QUICK, *VARY, "--out", str(out))
    assert res.returncode == 0, res.stderr
    assert "4 done already, 0 to run" in res.stderr
    assert summaries(out) == before
    data = json.loads((out / "study.json").read_text())
    assert all(r["resumed"] for r in data["rows"])
    assert all(r["peak_rss_mb"] > 0 for r in data["rows"])  # kept from the first run
    # A deleted variant and a half-written one (no summary.json) are rerun, nothing else.
    gone, half = sorted(before)[:2]
    shutil.rmtree(out / "variants" / gone)
    (out / "variants" / half / "summary.json").unlink()
    res = study("gaussian-hill", *QUICK, *VARY, "--out", str(out), "--quiet")
    assert res.returncode == 0, res.stderr
    after = summaries(out)
    assert set(after) == set(before)
    assert {k for k in before if after[k] != before[k]} == {gone, half}
    data = json.loads((out / "study.json").read_text())
    assert sum(not r["resumed"] for r in data["rows"]) == 2
    assert all(r["status"] == "ok" for r in data["rows"])


def one_error_line(err, *names):
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:"), err
    for name in names:
        assert name in lines[0], (name, lines[0])


def test_a_study_of_another_scene_is_refused(two_by_two):
    """A study folder holds one scene's study: another scene's is refused, nothing touched."""
    out = two_by_two
    files = sorted(p for p in out.rglob("*") if p.is_file())
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files}
    res = study("zalesak", *QUICK, "--vary", "time.courant=2,5", "--out", str(out))
    assert res.returncode == 2
    one_error_line(res.stderr, str(out), "gaussian-hill", "zalesak")
    assert sorted(p for p in out.rglob("*") if p.is_file()) == files
    assert {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in files} == before


def test_tables_honour_the_umask(two_by_two):
    mask = os.umask(0o022)
    os.umask(mask)
    for name in ("study.csv", "study.json", "study.md", "error_vs_wall.png"):
        assert (two_by_two / name).stat().st_mode & 0o777 == 0o666 & ~mask, name


def test_an_out_that_cannot_be_a_folder_is_an_error_line(tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("keep")
    for out in (afile / "sub", Path("/proc/pfem2x-study")):
        res = study("gaussian-hill", *QUICK, "--vary", "time.courant=2,5", "--out", str(out))
        assert res.returncode == 2
        one_error_line(res.stderr, f"--out {out}")
    assert afile.read_text() == "keep" and sorted(tmp_path.iterdir()) == [afile]


def test_diverged_variant_is_a_row(tmp_path):
    # Explicit Euler (theta = 0) on T' = 1e6 T overflows; implicit Euler stays bounded.
    out = tmp_path / "div"
    res = study(
        "gaussian-hill",
        *QUICK,
        "--set",
        "effects.reaction=true",
        "--set",
        "transport.reaction=-1e6",
        "--set",
        "time.courant=0.2",
        "--vary",
        "method.theta=0,1",
        "--out",
        str(out),
    )
    assert res.returncode == 0, res.stderr
    rows = {r["method.theta"]: r for r in json.loads((out / "study.json").read_text())["rows"]}
    assert rows[0]["status"] == "diverged"
    assert rows[0]["exit_code"] == 3
    assert "diverged" in rows[0]["message"]
    assert rows[1]["status"] == "ok"
    assert "1 ok, 1 diverged" in res.stderr
    assert "diverged" in (out / "study.md").read_text()


@pytest.mark.parametrize(
    "vary, needle",
    [
        ("time.courantt=1,2", "time.courantt"),
        ("time.courant=", "time.courant"),
        ("time.courant=1,,2", "time.courant"),
        ("time.courant=1,-2", "time.courant"),
        ("params.omegaa=1,2", "params.omegaa"),
        ("method.frame=eulerian,nope", "method.frame"),
        ("time.courant", "time.courant"),
        ("time.courant,method.theta=[2]", "time.courant,method.theta"),
        ("time.courant,method.theta=2,5", "time.courant,method.theta"),
        ("time.courant,method.theta=[2,0.5],[2,0.5]", "time.courant,method.theta"),
        ("time.courant,time.courant=[1,2]", "time.courant"),
        ("time.courant,method.thetaa=[2,0.5]", "method.thetaa"),
        ("time.courant,method.theta=[2,-1]", "method.theta"),
    ],
)
def test_bad_vary(tmp_path, vary, needle):
    out = tmp_path / "never"
    res = study("gaussian-hill", "--variant", "small", "--vary", vary, "--out", str(out))
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:"), res.stderr
    assert needle in lines[0]
    assert not out.exists()


def test_keys_varied_together(tmp_path):
    # One axis of two keys: its points, not their product (2 x 2 runs, not 2 x 4).
    out = tmp_path / "joint"
    res = study(
        "gaussian-hill",
        *QUICK,
        "--vary",
        "time.courant=2,5",
        "--vary",
        'method.frame,method.theta=["eulerian",0.5],["lagrangian",1]',
        "--out",
        str(out),
        "--quiet",
    )
    assert res.returncode == 0, res.stderr
    with open(out / "study.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    got = {(r["time.courant"], r["method.frame"], r["method.theta"]) for r in rows}
    assert got == {
        ("2", "eulerian", "0.5"),
        ("2", "lagrangian", "1"),
        ("5", "eulerian", "0.5"),
        ("5", "lagrangian", "1"),
    }
    assert all(r["status"] == "ok" and r["frame"] == r["method.frame"] for r in rows)
    info = json.loads((out / "study.json").read_text())
    assert info["keys"] == ["time.courant", "method.frame", "method.theta"]
    md = (out / "study.md").read_text()  # the axis as given, not as two products
    assert '- `--vary method.frame,method.theta=["eulerian",0.5],["lagrangian",1]`' in md
    assert fmt_value(False) == "false" and fmt_value(True) == "true" and fmt_value(0.5) == "0.5"


def test_failed_child_is_a_row(tmp_path):
    # A child that exits 1 without a summary (here: not even Python) is a "failed" row.
    res = run_study(
        "gaussian-hill",
        ["time.courant=2"],
        variant="small",
        out=tmp_path / "fail",
        quiet=True,
        python=shutil.which("false") or "/bin/false",
    )
    assert res.exit_code == 0
    assert [r["status"] for r in res.rows] == ["failed"]
    assert res.rows[0]["exit_code"] == 1
    assert (tmp_path / "fail" / "study.csv").is_file()


DRIVER_ONLY = """
import shutil, sys
import pfem2x.cli
from pfem2x.study import run_study
res = run_study("gaussian-hill", ["time.courant=2,5"], variant="small", out=sys.argv[1],
                quiet=True, python=shutil.which("false") or "/bin/false")
assert [r["status"] for r in res.rows] == ["failed", "failed"], res.rows
heavy = ("dolfinx", "mpi4py", "petsc4py", "ufl", "basix", "numba")
print(" ".join(sorted({m.split(".")[0] for m in sys.modules} & set(heavy))))
"""


def test_driver_imports_neither_dolfinx_nor_mpi(tmp_path):
    # The driver is serial: planning, running the children and writing the tables load
    # no DOLFINx, MPI or numba (the children do).
    res = subprocess.run(
        [sys.executable, "-c", DRIVER_ONLY, str(tmp_path / "light")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == ""
    assert (tmp_path / "light" / "study.csv").is_file()


def test_split_values():
    assert split_values("0.5,2,5") == ["0.5", "2", "5"]
    assert split_values("[50,200], [100,400]") == ["[50,200]", "[100,400]"]
    assert split_values('"a,b",c') == ['"a,b"', "c"]
    with pytest.raises(StudyError):
        split_values("[1,2")
    key, texts, values = parse_vary("mesh.cells=[8,8],[12,12]")
    assert key == "mesh.cells" and texts == ["[8,8]", "[12,12]"]
    assert values == [[8, 8], [12, 12]]
    keys, texts, values = parse_axis('mesh.cells,method.frame=[[8,8],"eulerian"],[[12,12],"x"]')
    assert keys == ["mesh.cells", "method.frame"]
    assert texts == [
        {"mesh.cells": "[8,8]", "method.frame": '"eulerian"'},
        {"mesh.cells": "[12,12]", "method.frame": '"x"'},
    ]
    assert values == [
        {"mesh.cells": [8, 8], "method.frame": "eulerian"},
        {"mesh.cells": [12, 12], "method.frame": "x"},
    ]
    assert parse_axis("time.courant=1,2")[1] == [{"time.courant": "1"}, {"time.courant": "2"}]


def test_pareto_front():
    pts = [(1.0, 5.0), (2.0, 3.0), (3.0, 4.0), (4.0, 1.0), (0.5, 9.0)]
    assert pareto_front(pts) == [4, 0, 1, 3]
