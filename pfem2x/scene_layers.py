"""Layers of a scene: its frame tables, a variant and ``--set``, applied in that order.

A scene file may hold, besides its sections, ``[variants.NAME]`` tables (chosen by
``--variant NAME``) and ``[frames.FRAME]`` tables (applied when ``method.frame`` is
``FRAME``, whichever way it was chosen). Both hold dotted keys
(``"flow.pressure_step" = "total"``; nested tables are read as their dotted leaves).
A variant may hold frame tables of its own, ``[variants.NAME.frames.FRAME]``: the
variant's keys for one frame (a large-step variant that each frame runs with its own
keys). :func:`apply_layers` writes them into the scene's raw dict: first the table of
the run's frame, then the variant, then the variant's table of the run's frame, then
``--set``, each layer over the ones before it, so that a variant or a ``--set`` always
wins over a frame table. A layer that sets exactly one of ``time.dt`` and
``time.courant`` replaces the other; one that sets ``time.dt`` also drops an earlier
``time.adaptive`` (a step re-evaluated from ``time.courant``).
"""

from __future__ import annotations

import difflib
from typing import Any

from pfem2x.scene_readers import FRAME_KEYS
from pfem2x.scene_schema import PHASE_KEYS, SCHEMA, SceneError

__all__ = ["Layer", "apply_layers", "check_frames", "check_variants", "flatten", "frame_layers"]

#: One layer: (dotted key as parts, value, where the key was given).
Layer = list[tuple[list[str], Any, str]]

_STEP = ("dt", "courant")


def flatten(table: dict[str, Any], where: str) -> Layer:
    """A table of dotted keys as one layer (nested tables are read as their leaves).

    Parameters
    ----------
    table:
        ``{"flow.rtol": 1e-6}``, ``{"flow": {"rtol": 1e-6}}`` or a mix.
    where:
        The table's name in messages (e.g. ``"variants.small"``).

    Returns
    -------
    Layer
        ``(parts, value, where)`` per leaf, in the table's order.

    Raises
    ------
    SceneError
        For an empty part of a key (``"flow..rtol"``) or a key given twice.
    """
    out: Layer = []
    seen: set[tuple[str, ...]] = set()
    for k, v in table.items():
        parts = [p.strip() for p in str(k).split(".")]
        if any(not p for p in parts):
            raise SceneError(f"{where}.{k}: bad key")
        if isinstance(v, dict) and v:
            leaves = [([*parts, *sub], val) for sub, val, _ in flatten(v, f"{where}.{k}")]
        else:
            leaves = [(parts, v)]
        for full, val in leaves:
            name = f"{where}.{'.'.join(full)}"
            if tuple(full) in seen:
                raise SceneError(f"{name}: given twice")
            seen.add(tuple(full))
            out.append((full, val, name))
    return out


def check_frames(raw: dict[str, Any]) -> dict[str, Layer]:
    """The scene's ``[frames.*]`` tables as layers, each key and value checked.

    ``raw`` is the scene as read from TOML (not modified); see :func:`frame_layers`.
    """
    return frame_layers(raw, raw.get("frames", {}), "frames")


def check_variants(raw: dict[str, Any]) -> None:
    """Check every ``[variants.NAME]`` table of a scene, whichever variant a run takes.

    Each key must be a key of the scene's sections (its value checked as there), a
    ``params.NAME`` or a ``phases.NAME.KEY``; the variant's own frame tables are
    checked as :func:`frame_layers` checks them. ``raw`` is not modified.

    Parameters
    ----------
    raw
        The scene as read from TOML.

    Raises
    ------
    SceneError
        Naming the first bad key (``variants.NAME.section.key``), including keys
        that would write into ``[variants]`` or ``[frames]``.
    """
    variants = raw.get("variants", {})
    if not isinstance(variants, dict):
        raise SceneError("variants: expected tables [variants.NAME] of dotted keys")
    for name, table in variants.items():
        where = f"variants.{name}"
        if not isinstance(table, dict):
            raise SceneError(f"{where}: expected a table of dotted keys")
        table = dict(table)
        frame_layers(raw, table.pop("frames", {}), f"{where}.frames")
        for parts, value, at in flatten(table, where):
            _check_variant_key(parts, value, at, where)


def _check_variant_key(parts: list[str], value: Any, at: str, where: str) -> None:
    """Refuse one key of a variant that no scene section, param or phase has."""
    sec = parts[0]
    if sec in ("frames", "variants"):
        raise SceneError(
            f"{at}: a variant cannot set [{sec}] tables (a variant's frame tables are "
            f"[{where}.frames.FRAME])"
        )
    if sec in SCHEMA and len(parts) == 2:
        if parts[1] not in SCHEMA[sec]:
            near = difflib.get_close_matches(parts[1], list(SCHEMA[sec]), n=1, cutoff=0.5)
            hint = f" (did you mean {where}.{sec}.{near[0]}?)" if near else ""
            raise SceneError(f"{at}: unknown key{hint}")
        SCHEMA[sec][parts[1]].check(at, value)
        return
    if sec == "params" and len(parts) == 2:
        return  # checked with the scene's params
    if sec == "phases" and len(parts) == 3 and parts[2] in PHASE_KEYS:
        return
    raise SceneError(
        f"{at}: not a key of the scene (section.key, params.NAME or phases.NAME.KEY; "
        f"phase keys: {', '.join(PHASE_KEYS)})"
    )


def frame_layers(raw: dict[str, Any], frames: Any, where: str) -> dict[str, Layer]:
    """Frame tables (``[frames.*]`` or a variant's ``frames``) as layers, each key checked.

    Parameters
    ----------
    raw:
        The scene as read from TOML (its physics: which frames read a key).
    frames:
        The tables, frame name → table of dotted keys.
    where:
        Their name in messages (``"frames"``, ``"variants.NAME.frames"``).

    Returns
    -------
    dict
        Frame name → its layer (:func:`flatten`).

    Raises
    ------
    SceneError
        For a frame that ``method.frame`` cannot take, a key outside the schema's
        sections, a value the key refuses (named ``WHERE.FRAME.section.key``), a key
        that only other frames read, or a table that sets ``method.frame`` itself.
    """
    if not isinstance(frames, dict):
        raise SceneError(f"{where}: expected tables [{where}.FRAME] of dotted keys")
    known = SCHEMA["method"]["frame"].check
    out: dict[str, Layer] = {}
    for name, table in frames.items():
        try:
            known(f"{where}.{name}", name)
        except SceneError as exc:
            raise SceneError(f"{exc} (a frame table is named by method.frame)") from None
        if not isinstance(table, dict):
            raise SceneError(f"{where}.{name}: expected a table of dotted keys")
        layer = flatten(table, f"{where}.{name}")
        for parts, value, at in layer:
            if parts[:2] == ["method", "frame"]:
                raise SceneError(f"{at}: a frame table cannot choose the frame")
            if len(parts) != 2 or parts[0] not in SCHEMA or parts[1] not in SCHEMA[parts[0]]:
                raise SceneError(
                    f"{at}: not a key of the scene's sections (e.g. flow.rtol; "
                    "[phases] and [params] cannot be set per frame)"
                )
            SCHEMA[parts[0]][parts[1]].check(at, value)
            _read_by(raw, name, ".".join(parts), at)
        out[name] = layer
    return out


def _read_by(raw: dict[str, Any], frame: str, key: str, where: str) -> None:
    """Refuse a frame table's key that only other frames of the scene's physics read."""
    scene = raw.get("scene")
    physics = scene.get("physics", "transport") if isinstance(scene, dict) else "transport"
    frames = FRAME_KEYS.get(physics, {}) if isinstance(physics, str) else {}
    readers = [f for f, keys in frames.items() if key in keys]
    if readers and frame not in readers:
        raise SceneError(
            f"{where}: the {frame} frame does not read it (read by: {', '.join(readers)})"
        )


def _frame(raw: dict[str, Any], later: list[Layer]) -> Any:
    method = raw.get("method")
    frame = SCHEMA["method"]["frame"].default
    if isinstance(method, dict):
        frame = method.get("frame", frame)
    for layer in later:
        for parts, value, _ in layer:
            if parts == ["method", "frame"]:
                frame = value
    return frame


def _set_dotted(raw: dict, parts: list[str], value: Any, where: str) -> None:
    d = raw
    for p in parts[:-1]:
        nxt = d.setdefault(p, {})
        if not isinstance(nxt, dict):
            raise SceneError(f"{where}: {p!r} is not a section")
        d = nxt
    d[parts[-1]] = value


def _step_keys(layer: Layer) -> set[str]:
    return {p[1] for p, _, _ in layer if len(p) == 2 and p[0] == "time" and p[1] in _STEP}


def apply_layers(
    raw: dict[str, Any],
    variant: Layer,
    sets: Layer,
    variant_frames: dict[str, Layer] | None = None,
) -> Layer:
    """Write the run's frame table, ``variant``, its frame table, ``sets`` into ``raw``.

    Parameters
    ----------
    raw:
        The scene as read from TOML (changed in place); its ``[frames.*]`` tables stay
        in it.
    variant, sets:
        The layers of ``--variant`` and of ``--set`` (:func:`flatten`).
    variant_frames:
        The variant's own frame tables (:func:`frame_layers`); the run's frame's is
        applied after ``variant``.

    Returns
    -------
    Layer
        The frame table's entries the run keeps (those no later layer replaces).

    Raises
    ------
    SceneError
        From :func:`check_frames`, or for a layer that writes into a key that is not
        a table (``--set time.dt.x=1``).
    """
    frames = check_frames(raw)
    frame = _frame(raw, [variant, sets])
    chosen = frames.get(frame, []) if isinstance(frame, str) else []
    own = (variant_frames or {}).get(frame, []) if isinstance(frame, str) else []
    for layer in (chosen, variant, own, sets):
        step = _step_keys(layer)
        if len(step) == 1 and isinstance(raw.get("time"), dict):
            given = step.pop()
            raw["time"].pop(_STEP[1 - _STEP.index(given)], None)
            if given == "dt" and ["time", "adaptive"] not in [p for p, _, _ in layer]:
                raw["time"].pop("adaptive", None)  # re-evaluated from time.courant only
        for parts, value, where in layer:
            _set_dotted(raw, parts, value, where)
    after = variant + own + sets
    later = {tuple(p) for p, _, _ in after}
    if _step_keys(after):
        later |= {("time", k) for k in _STEP}
    if "dt" in _step_keys(after):
        later.add(("time", "adaptive"))
    return [e for e in chosen if tuple(e[0]) not in later]
