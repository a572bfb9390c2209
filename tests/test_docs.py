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


def test_readme_names_every_command_and_section():
    readme = (ROOT / "README.md").read_text()
    for word in (
        "make demo",
        "make test",
        "make test-011",
        "pfem2x run",
        "pfem2x check",
        "pfem2x scenes",
        "pfem2x study",
        "--resume",
        "docs/SCENES.md",
    ):
        assert word in readme, word
    for sec in SCHEMA:
        assert f"[{sec}]" in readme or sec in ("flow",), sec
