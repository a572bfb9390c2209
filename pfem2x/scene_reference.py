"""The scene reference: docs/SCENES.md rendered from :data:`pfem2x.scene_schema.SCHEMA`.

Each key's type is read from its checker, its default and doc line from the
:class:`~pfem2x.scene_schema.Key`; :data:`~pfem2x.scene_readers.FRAME_KEYS` gives the table
of which frame reads which numerical switch. ``python -m pfem2x.scene`` prints it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pfem2x.scene_readers import FLOW_COMMON_KEYS, FRAME_KEYS
from pfem2x.scene_schema import SCHEMA

__all__ = ["schema_markdown"]


def _kind(check: Callable[[str, Any], Any]) -> str:
    base = getattr(check, "__qualname__", "").split(".")[0]
    cells = [c.cell_contents for c in (getattr(check, "__closure__", None) or ())]
    if base == "choice":
        opts = next((c for c in cells if isinstance(c, tuple)), ())
        return " \\| ".join(f"`{o}`" for o in opts)
    if base == "list_of":
        inner = next((c for c in cells if callable(c)), None)
        return f"list of {_kind(inner)}" if inner else "list"
    if base == "auto_or":
        inner = next((c for c in cells if callable(c)), None)
        return f"`auto` or {_kind(inner)}" if inner else "`auto` or value"
    names = {
        "number": "number",
        "integer": "integer",
        "boolean": "boolean",
        "string": "string",
        "expr_text": "expression or number",
        "bounds_check": "[lo, hi] corners",
        "cells_check": "integer or list of integers",
        "times_check": "list of times",
        "scene_name": "string (folder name)",
        "case_name": "string (case name)",
    }
    return names.get(base, base or "value")


def schema_markdown() -> str:
    """Every scene key with its type, default and meaning, as markdown (docs/SCENES.md)."""
    lines = [
        "# Scene keys",
        "",
        "Generated from `pfem2x/scene_schema.py` by `python -m pfem2x.scene > docs/SCENES.md`",
        "(a test checks that this file is current). Expressions: see docs/USAGE.md.",
        "",
    ]
    for sec, keys in SCHEMA.items():
        lines += [f"## [{sec}]", "", "| key | type | default | meaning |", "|---|---|---|---|"]
        for k, spec in keys.items():
            default = (
                "**required**"
                if spec.required
                else ("" if spec.default is None else f"`{spec.default!r}`")
            )
            doc = spec.doc.replace("|", "\\|")
            lines.append(f"| `{sec}.{k}` | {_kind(spec.check)} | {default} | {doc} |")
        lines.append("")
    lines += [
        "## [phases.NAME] (flow)",
        "",
        "| key | type | default | meaning |",
        "|---|---|---|---|",
        "| `density` | number > 0 | **required** | the phase's density |",
        "| `viscosity` | number >= 0 | `0.0` | dynamic viscosity |",
        "| `region` | expression | | where the phase is at t = 0 (truthy); exactly one of two |",
        "",
        "## [params], [frames.FRAME], [variants.NAME]",
        "",
        "`[params]`: named numbers usable in every expression (identifiers, not `x y z t`, not",
        "a function or constant name). `[frames.FRAME]` (`lagrangian`, `eulerian`,",
        '`characteristic`): dotted keys (`"flow.pressure_step" = "total"`) applied when',
        "`method.frame` is FRAME, however it was chosen; each key must be one of the sections'",
        "keys above (not `[phases]` or `[params]`) that the frame reads (the table below),",
        "every table's values are checked, and a frame table cannot set `method.frame`.",
        "`[variants.NAME]`: dotted keys applied by `--variant NAME`; a variant's own frame",
        "tables `[variants.NAME.frames.FRAME]` (checked as the scene's) hold its keys for one",
        "frame. Order: the scene's sections, the run's frame table, the variant, the variant's",
        "table of the run's frame, then every `--set` (a later layer wins; one that sets only",
        "one of `time.dt` and `time.courant` replaces the other; a `--set` of a table sets its",
        "keys). Neither kind of table can be changed by `--set`.",
        "",
    ]
    return "\n".join(lines + _frames_markdown())


def _frames_markdown() -> list[str]:
    lines = [
        "## Numerical switches by frame",
        "",
        "Which `method.*` and `flow.*` keys each frame reads (`method.frame` picks the frame;",
        "a key not listed for a frame is validated but has no effect there).",
        "",
        "| physics | frame | reads |",
        "|---|---|---|",
    ]
    for physics, frames in FRAME_KEYS.items():
        for frame, keys in frames.items():
            lines.append(f"| {physics} | `{frame}` | {', '.join(f'`{k}`' for k in keys)} |")
    common = ", ".join(f"`{k}`" for k in FLOW_COMMON_KEYS)
    lines += ["", f"Both flow frames also read {common}.", ""]
    return lines
