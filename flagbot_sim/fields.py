"""Declared fields: the metadata of a value (unit, bounds, choices, lengths), its check, and the short text of a
value for an error message.

The scene (:mod:`flagbot_sim.scene`) declares every key with :func:`spec` as a dataclass field's metadata and
checks what a file or an override gives with :func:`check_value`; the nodes' parameters use the same texts. Every
refusal is a :class:`SceneError` (the scene's error: ``flagbot_sim.scene`` uses and exports it).
"""
from __future__ import annotations

import dataclasses
import math
import reprlib
import unicodedata
from typing import Any


class SceneError(ValueError):
    """A scene file, value or override is invalid. The message names the key and the allowed values."""


_REPR = reprlib.Repr()
_REPR.maxlist = _REPR.maxtuple = 6
_REPR.maxdict = 4
_REPR.maxstring = _REPR.maxother = 60
_REPR.maxlevel = 3


def short(value: Any, limit: int = 120) -> str:
    """``repr(value)`` for an error message: long lists and strings elided, deep nesting cut, at most ``limit``
    characters (a refused 1e6-element array is not echoed back)."""
    try:
        text = _REPR.repr(value)
    except Exception:                                       # noqa: BLE001 - a message must never fail
        text = f"<{type(value).__name__}>"
    if isinstance(value, str) and len(value) > _REPR.maxstring:
        text += f" ({len(value)} characters)"
    elif isinstance(value, (list, tuple, dict)) and len(value) > _REPR.maxlist:
        text += f" ({len(value)} items)"
    return text if len(text) <= limit else text[:limit - 3] + "..."


_CONTROL_NAMES = {"\n": "a newline", "\r": "a carriage return", "\t": "a tab", "\0": "a NUL",
                  "\x1b": "an escape", "\u2028": "a line separator", "\u2029": "a paragraph separator"}


def control_character(text: str, allowed: str = "") -> str | None:
    """The first control character of ``text`` not in ``allowed``, named for a message ('a newline (U+000A)'), or
    None. Control characters are Unicode's Cc (C0 controls, DEL, C1 controls) and the line and paragraph
    separators: what breaks a value over lines (an override's newline started a second TOML key, which was then
    dropped) or cuts it short where it becomes a C string (a NUL ends a file name)."""
    for c in text:
        if c not in allowed and (unicodedata.category(c) in ("Cc", "Zl", "Zp")):
            return f"{_CONTROL_NAMES.get(c, 'a control character')} (U+{ord(c):04X})"
    return None


def names(items, limit: int = 5) -> str:
    """Some names for a message: the first ``limit``, then how many more."""
    items = list(items)
    text = ", ".join(short(x, 60) for x in items[:limit])
    return text + (f" and {len(items) - limit} more" if len(items) > limit else "")


def spec(unit: str = "", *, gt: float | None = None, ge: float | None = None, lt: float | None = None,
         le: float | None = None, doc: str = "", choices: tuple | None = None, items: str | None = None,
         length: int | None = None, max_len: int | None = None, one_line: bool = False, why: str = "") -> dict:
    """Field metadata: unit, bounds, choices; for lists the type of their ``items`` ('str' or 'number') and an
    exact ``length``; for strings (and lists) a ``max_len``; ``one_line`` strings hold no line breaks or tabs;
    ``why`` the reason for the bounds, told with an out-of-range refusal."""
    return {"unit": unit, "gt": gt, "ge": ge, "lt": lt, "le": le, "doc": doc, "choices": choices, "items": items,
            "length": length, "max_len": max_len, "one_line": one_line, "why": why}


def format_bounds(meta: dict) -> str:
    """The allowed range of a field as text, e.g. '>0 <=10' or 'auto|arrow|splu'."""
    parts = [f"{word}{meta[op]:g}" for op, word in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
             if meta.get(op) is not None]
    if meta.get("choices"):
        parts.append("|".join(meta["choices"]))
    if meta.get("length"):
        parts.append(f"{meta['length']} {meta.get('items') or 'item'}s")
    return " ".join(parts)


def number(key: str, meta: dict, value: Any, what: str = "") -> float:
    """``value`` as a finite float, or a SceneError naming ``key``."""
    unit = meta["unit"] or "dimensionless"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"{key}{what} must be a number ({unit}), got {short(value)}")
    try:
        value = float(value)
    except OverflowError:                       # an integer beyond the float range
        raise SceneError(f"{key}{what} = {short(value)} is out of range for a number ({unit})") from None
    if not math.isfinite(value):
        raise SceneError(f"{key}{what} must be finite, got {value!r}")
    return value


_BOUNDS = (("gt", lambda a, b: a > b, ">"), ("ge", lambda a, b: a >= b, ">="),
           ("lt", lambda a, b: a < b, "<"), ("le", lambda a, b: a <= b, "<="))


def check_bounds(key: str, meta: dict, value: Any) -> None:
    if all(meta.get(bound) is None or op(value, meta[bound]) for bound, op, _ in _BOUNDS):
        return
    unit = f" {meta['unit']}" if meta["unit"] else ""
    allowed = " and ".join(f"{word} {meta[bound]:g}{unit}" for bound, _, word in _BOUNDS
                           if meta.get(bound) is not None)
    why = f": {meta['why']}" if meta.get("why") else ""
    raise SceneError(f"{key} = {short(value)}{unit} is out of range: must be {allowed}{why}")


def check_value(key: str, f: dataclasses.Field, value: Any) -> Any:
    """``value`` of the declared field ``f`` (named ``key`` in messages), checked against its type, bounds,
    choices and lengths and converted (ints to floats, lists to tuples), or a SceneError saying what is wrong."""
    meta = f.metadata
    default = f.default
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise SceneError(f"{key} must be true or false, got {short(value)}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            if isinstance(value, float) and value.is_integer():
                # beyond 2**53 a float is not an exact integer: left a float, the range check refuses it
                value = int(value) if abs(value) <= 2 ** 53 else value
            else:
                raise SceneError(f"{key} must be an integer, got {short(value)}")
    elif isinstance(default, float):
        value = number(key, meta, value)
    elif isinstance(default, str):
        if not isinstance(value, str):
            raise SceneError(f"{key} must be a string, got {short(value)}")
        if meta.get("max_len") and len(value) > meta["max_len"]:
            raise SceneError(f"{key} is {len(value)} characters long: at most {meta['max_len']} allowed")
        bad = control_character(value, "" if meta.get("one_line") else "\t\n\r")
        if bad:
            raise SceneError(f"{key} = {short(value)} holds {bad}" +
                             (": it is one line of printable text" if meta.get("one_line") else ""))
    elif isinstance(default, tuple):
        if not isinstance(value, (list, tuple)):
            raise SceneError(f"{key} must be a list, got {short(value)}")
        if meta.get("length") is not None and len(value) != meta["length"]:
            raise SceneError(f"{key} must be a list of {meta['length']} {meta.get('items') or 'item'}s"
                             f"{' (' + meta['unit'] + ')' if meta['unit'] else ''}, got {short(value)}")
        if meta.get("max_len") and len(value) > meta["max_len"]:
            raise SceneError(f"{key} has {len(value)} items: at most {meta['max_len']} allowed")
        if meta.get("items") == "str":
            bad = [x for x in value if not isinstance(x, str)]
            if bad:
                raise SceneError(f"{key} must be a list of names (strings), got {short(value)}")
        elif meta.get("items") == "number":
            value = [number(key, meta, x, f"[{i}]") for i, x in enumerate(value)]
            for x in value:
                check_bounds(key, meta, x)
        return tuple(value)
    if meta.get("choices") and value not in meta["choices"]:
        raise SceneError(f"{key} = {short(value)} is not allowed; choose one of {', '.join(meta['choices'])}")
    check_bounds(key, meta, value)
    return value
