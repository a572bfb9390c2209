"""Study input: ``--vary`` lists, the product of variants, each checked before anything runs.

:func:`plan_study` parses the options and loads the scene of every variant with
:func:`pfem2x.scene.load_scene`, so that bad input is refused (:class:`StudyError`,
naming the key) before anything is run or written.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pfem2x.scene import Scene, SceneError, load_scene, parse_override


class StudyError(SceneError):
    """Bad study input; the message names the key or option."""


@dataclass
class Variant:
    """One point of the study's product.

    Attributes
    ----------
    slug:
        Folder name under ``DIR/variants``.
    texts:
        Varied key → value as given on the command line.
    values:
        Varied key → value parsed as TOML.
    overrides:
        The child's ``--set`` list (the study's ``--set`` then the varied keys).
    frame:
        The variant's ``method.frame``.
    resolved:
        The resolved scene text the child writes to ``scene.toml`` (resume check).
    """

    slug: str
    texts: dict[str, str]
    values: dict[str, Any]
    overrides: list[str]
    frame: str
    resolved: str

    def label(self) -> str:
        """``key=value`` pairs, for progress lines and plot labels."""
        return " ".join(f"{k}={v}" for k, v in self.texts.items())


def split_values(text: str) -> list[str]:
    """Split a value list on the commas at bracket depth 0 (outside TOML strings).

    ``"[50,200],[100,400]"`` → ``["[50,200]", "[100,400]"]``; items are stripped.

    Raises
    ------
    StudyError
        On unbalanced brackets or quotes.
    """
    items, cur, depth, quote = [], [], 0, ""
    for ch in text:
        if quote:
            cur.append(ch)
            if ch == quote:
                quote = ""
            continue
        if ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
            if depth < 0:
                raise StudyError(f"unbalanced {ch!r} in {text!r}")
        elif ch == "," and depth == 0:
            items.append("".join(cur).strip())
            cur = []
            continue
        cur.append(ch)
    if quote or depth:
        raise StudyError(f"unclosed {'quote' if quote else 'bracket'} in {text!r}")
    items.append("".join(cur).strip())
    return items


def parse_vary(text: str) -> tuple[str, list[str], list[Any]]:
    """Parse ``--vary KEY=V1,V2,...`` into the key, value texts and TOML values.

    Raises
    ------
    StudyError
        Naming the key: no ``=``, bad key, empty list or item, unreadable or
        repeated value.
    """
    if "=" not in text:
        raise StudyError(f"--vary {text}: expected KEY=V1,V2,..., e.g. time.courant=1,2,4")
    key, _, vals = text.partition("=")
    key = key.strip()
    if not key or any(not p.strip() or p != p.strip() for p in key.split(".")):
        raise StudyError(f"--vary {text}: bad key {key!r}")
    if not vals.strip():
        raise StudyError(f"--vary {key}: empty value list (expected {key}=V1,V2,...)")
    try:
        texts = split_values(vals)
    except StudyError as exc:
        raise StudyError(f"--vary {key}: {exc}") from None
    values: list[Any] = []
    for i, v in enumerate(texts):
        if not v:
            raise StudyError(f"--vary {key}: value {i + 1} of {vals.strip()!r} is empty")
        try:
            _, value = parse_override(f"{key}={v}")
        except SceneError as exc:
            raise StudyError(str(exc).replace("--set ", "--vary ", 1)) from None
        if any(_same(value, u) for u in values):
            raise StudyError(f"--vary {key}: value {v} is given twice")
        values.append(value)
    return key, texts, values


def _same(a: Any, b: Any) -> bool:
    if is_number(a) and is_number(b):
        return a == b
    return type(a) is type(b) and a == b


def is_number(v: Any) -> bool:
    """Whether ``v`` is an int or float (not a bool)."""
    return isinstance(v, int | float) and not isinstance(v, bool)


def _slug_part(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.+-]+", "-", text).strip("-.") or "x"


def _make_slug(texts: dict[str, str]) -> str:
    slug = "_".join(f"{k}-{_slug_part(v)}" for k, v in texts.items())
    if len(slug) > 120:
        digest = hashlib.sha1(json.dumps(texts, sort_keys=True).encode()).hexdigest()[:10]
        slug = f"{slug[:100]}_{digest}"
    return slug


def plan_study(
    scene: str,
    vary: Sequence[str],
    sets: Sequence[str] = (),
    variant: str | None = None,
) -> tuple[Scene, list[Variant]]:
    """Parse the options and validate every variant (nothing is run or written).

    Parameters
    ----------
    scene:
        A scene file or built-in scene name.
    vary:
        ``KEY=V1,V2,...`` strings.
    sets:
        ``KEY=VALUE`` overrides common to every variant.
    variant:
        The scene's ``[variants.NAME]`` to apply first.

    Returns
    -------
    tuple
        The base scene (``sets`` and ``variant`` applied) and the variants in
        product order (the last ``--vary`` key varies fastest).

    Raises
    ------
    SceneError
        (or :class:`StudyError`) with a message naming the key.
    """
    if not vary:
        raise StudyError("--vary: give at least one KEY=V1,V2,...")
    base = load_scene(scene, list(sets), variant)
    set_keys = {".".join(parse_override(s)[0]) for s in sets}
    axes: list[tuple[str, list[str], list[Any]]] = []
    for text in vary:
        key, texts, values = parse_vary(text)
        if any(key == k for k, _, _ in axes):
            raise StudyError(f"--vary {key}: the key is varied twice")
        if key in set_keys:
            raise StudyError(f"--vary {key}: the key is also given with --set")
        parts = key.split(".")
        if parts[0] == "params" and len(parts) == 2 and parts[1] not in base.params:
            known = ", ".join(sorted(base.params)) or "none"
            raise StudyError(f"{key}: unknown parameter of scene {base.name} (has: {known})")
        if parts[0] == "variants":
            raise StudyError(f"--vary {key}: use --variant NAME for the scene's variants")
        axes.append((key, texts, values))
    variants: list[Variant] = []
    seen: set[str] = set()
    for combo in itertools.product(*(range(len(t)) for _, t, _ in axes)):
        texts = {k: t[i] for (k, t, _), i in zip(axes, combo, strict=True)}
        values = {k: v[i] for (k, _, v), i in zip(axes, combo, strict=True)}
        overrides = list(sets) + [f"{k}={v}" for k, v in texts.items()]
        label = ", ".join(f"{k}={v}" for k, v in texts.items())
        try:
            sc = load_scene(scene, overrides, variant)
        except SceneError as exc:
            raise StudyError(f"{exc} (study variant {label})") from None
        slug = _make_slug(texts)
        if slug in seen:  # e.g. values differing only in punctuation
            digest = hashlib.sha1(json.dumps(texts, sort_keys=True).encode()).hexdigest()[:10]
            slug = f"{slug[:100]}_{digest}"
        seen.add(slug)
        variants.append(Variant(slug, texts, values, overrides, sc.frame, sc.resolved_toml()))
    return base, variants
