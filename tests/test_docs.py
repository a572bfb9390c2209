"""Documentation that must stay true to the code."""

from pathlib import Path

from pfem2x.scene import SCHEMA, schema_markdown

ROOT = Path(__file__).resolve().parent.parent


def test_scene_reference_is_current():
    text = (ROOT / "docs" / "SCENES.md").read_text()
    assert text == schema_markdown(), "regenerate: python -m pfem2x.scene > docs/SCENES.md"


def test_every_scene_key_is_documented():
    missing = [f"{s}.{k}" for s, keys in SCHEMA.items() for k, spec in keys.items() if not spec.doc]
    missing = [m for m in missing if m not in ("scene.name",)]
    assert not missing, missing


def test_readme_points_to_the_reference():
    readme = (ROOT / "README.md").read_text()
    for word in (
        "make demo",
        "make test",
        "docs/USAGE.md",
        "docs/SCENES.md",
        "docs/RESULTS.md",
        "docs/BENCHMARKS.md",
    ):
        assert word in readme, word


def test_usage_names_every_command_and_section():
    usage = (ROOT / "docs" / "USAGE.md").read_text()
    for word in (
        "make demo",
        "make test",
        "make test-011",
        "pfem2x run",
        "pfem2x check",
        "pfem2x scenes",
        "pfem2x study",
        "--resume",
        "SCENES.md",
    ):
        assert word in usage, word
    for sec in SCHEMA:
        assert f"[{sec}]" in usage or sec in ("flow",), sec


def test_rt_reference_table_is_made_from_its_data(tmp_path, capsys):
    """docs/data/rt-reference/table.md follows from the data stored beside it.

    ``benchmarks/rt_reference.py`` re-reads the trimmed run summaries and the stored
    interFoam tip histories and must print the very cells of the committed table; a bad
    source is one ``error:`` line and exit code 2.
    """
    import importlib.util

    import pytest

    spec = importlib.util.spec_from_file_location(
        "rt_reference", ROOT / "benchmarks" / "rt_reference.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    data = ROOT / "docs" / "data" / "rt-reference"
    names = sorted(p.name for p in (data / "pfem2x").iterdir())
    assert len(names) >= 10
    runs = [a for n in names for a in ("--run", f"{n}={data / 'pfem2x' / n}")]
    stored = ["r050_dt0.001", "r100_dt0.001", "r100_dt0.0025", "r100_co0.5_signm"]
    cases = sorted(p.name for p in (data / "interfoam").iterdir() if p.is_dir())
    runs += [a for n in cases for a in ("--case", f"{n}={data / 'interfoam' / n}")]
    names += stored + cases
    mod.main(["--stored", *stored, "--ref", "ls_aco0.5", *runs, "--md", str(tmp_path / "t.md")])
    ours = {r.split("|")[1].strip(): r for r in (tmp_path / "t.md").read_text().splitlines()[2:]}
    committed = {
        r.split("|")[1].strip(): r for r in (data / "table.md").read_text().splitlines()[2:]
    }
    assert set(ours) == set(names) and set(ours) <= set(committed)
    for n in names:  # the tip cells (columns 7-10), not the differences to another --ref
        assert ours[n].split("|")[7:11] == committed[n].split("|")[7:11], n
    # the differences at every output time: none to the reference itself, some to the others
    alltimes = {n: [c.strip() for c in ours[n].split("|")[13:15]] for n in names}
    assert alltimes["ls_aco0.5"] == ["0.0000", "0.0000"]
    assert all(float(v) > 0.0 for n in names if n != "ls_aco0.5" for v in alltimes[n] if v != "–")
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        mod.main(["--stored", "--ref", "x", "--run", f"x={tmp_path / 'none'}"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --run") and "summary.json" in err[0]
