"""Study input: ``--vary`` lists, the product of variants, each checked before anything runs.

A ``--vary`` is one axis of the product: one key and its values (``time.courant=1,2,4``)
or several keys varied together, one list of values per point
(``flow.extra_pass,flow.pressure_step=[false,"total"],[true,"increment"]``: two points,
not four), for comparing option sets against the step.

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
    if _bad_key(key):
        raise StudyError(f"--vary {text}: bad key {key!r}")
    texts = _value_texts(key, vals, "V1,V2")
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


def _value_texts(name: str, vals: str, expected: str) -> list[str]:
    """The value texts of ``--vary NAME=VALS`` (:func:`split_values`), none empty-listed."""
    if not vals.strip():
        raise StudyError(f"--vary {name}: empty value list (expected {name}={expected},...)")
    try:
        return split_values(vals)
    except StudyError as exc:
        raise StudyError(f"--vary {name}: {exc}") from None


def _bad_key(key: str) -> bool:
    return not key or any(not p.strip() or p != p.strip() for p in key.split("."))


def parse_axis(text: str) -> tuple[list[str], list[dict[str, str]], list[dict[str, Any]]]:
    """Parse one ``--vary``: a key and its values, or several keys varied together.

    ``KEY=V1,V2,...`` is :func:`parse_vary`. ``K1,K2,...=[a1,b1,...],[a2,b2,...]`` varies
    the keys together: each point is a TOML list with one value per key, in the keys'
    order (``flow.extra_pass,flow.pressure_step=[false,"total"],[true,"increment"]``).

    Returns
    -------
    tuple
        The keys, and per point the value texts and the TOML values (key → value).

    Raises
    ------
    StudyError
        Naming the keys: a bad or repeated key, a point that is not a list of one
        value per key, an unreadable or repeated point.
    """
    head, eq, vals = text.partition("=")
    if not eq or "," not in head:
        key, texts, values = parse_vary(text)
        return [key], [{key: t} for t in texts], [{key: v} for v in values]
    keys = [k.strip() for k in head.split(",")]
    name = ",".join(keys)
    for k in keys:
        if _bad_key(k):
            raise StudyError(f"--vary {text}: bad key {k!r}")
    if len(set(keys)) < len(keys):
        raise StudyError(f"--vary {name}: a key is given twice")
    example = "[" + ", ".join(f"v{i + 1}" for i in range(len(keys))) + "]"
    items = _value_texts(name, vals, example)
    texts: list[dict[str, str]] = []
    values: list[dict[str, Any]] = []
    for i, item in enumerate(items):
        subs = split_values(item[1:-1]) if item.startswith("[") and item.endswith("]") else []
        if len(subs) != len(keys) or not all(subs):
            raise StudyError(
                f"--vary {name}: point {i + 1} ({item or 'empty'}) is not a list of "
                f"{len(keys)} values, one per key (e.g. {example})"
            )
        point: dict[str, Any] = {}
        for k, sub in zip(keys, subs, strict=True):
            try:
                _, point[k] = parse_override(f"{k}={sub}")
            except SceneError as exc:
                raise StudyError(str(exc).replace("--set ", "--vary ", 1)) from None
        if any(all(_same(point[k], q[k]) for k in keys) for q in values):
            raise StudyError(f"--vary {name}: point {item} is given twice")
        texts.append(dict(zip(keys, subs, strict=True)))
        values.append(point)
    return keys, texts, values


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
        ``KEY=V1,V2,...`` strings, or ``K1,K2=[a1,b1],[a2,b2]`` for keys varied
        together (:func:`parse_axis`).
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
    axes: list[tuple[list[str], list[dict[str, str]], list[dict[str, Any]]]] = []
    for text in vary:
        keys, texts, values = parse_axis(text)
        for key in keys:
            if any(key in ks for ks, _, _ in axes):
                raise StudyError(f"--vary {key}: the key is varied twice")
            if key in set_keys:
                raise StudyError(f"--vary {key}: the key is also given with --set")
            parts = key.split(".")
            if parts[0] == "params" and len(parts) == 2 and parts[1] not in base.params:
                known = ", ".join(sorted(base.params)) or "none"
                raise StudyError(f"{key}: unknown parameter of scene {base.name} (has: {known})")
            if parts[0] == "variants":
                raise StudyError(f"--vary {key}: use --variant NAME for the scene's variants")
        axes.append((keys, texts, values))
    variants: list[Variant] = []
    seen: set[str] = set()
    for combo in itertools.product(*(range(len(t)) for _, t, _ in axes)):
        texts = {k: v for (_, t, _), i in zip(axes, combo, strict=True) for k, v in t[i].items()}
        values = {k: x for (_, _, v), i in zip(axes, combo, strict=True) for k, x in v[i].items()}
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
