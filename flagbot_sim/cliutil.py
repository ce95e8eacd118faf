"""Helpers shared by every command module: scene arguments and strict JSON output.

A leaf module: it imports nothing from flagbot_sim but :mod:`flagbot_sim.scene`, so any command module (beam,
sweep, bag tools, ...) can use it without importing :mod:`flagbot_sim.cli` back.
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Any


def add_scene_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", help="built-in scene name (design1, design2, clamped_flagellum) or a .toml path")
    p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                   help="override a scene value, e.g. --set robot.n_flagella=3 --set motor.omega_rpm=150")


def finite_float(text: str, where: str, error: type[Exception] = ValueError) -> float:
    """``text`` as a finite float, else ``error("WHERE: 'TEXT' is not a number" / "... is not finite")``."""
    try:
        x = float(text)
    except ValueError:
        raise error(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(x):
        raise error(f"{where}: {text!r} is not finite")
    return x


def json_default(o):
    """numpy arrays and scalars as plain JSON values (for ``json.dumps(default=...)``)."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "item"):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def finite_or_none(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, +-Inf) replaced by None, recursively (strict JSON has neither)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_or_none(v) for v in obj]
    if hasattr(obj, "tolist"):               # numpy array or scalar
        return finite_or_none(obj.tolist())
    return obj


def dumps(obj: Any, **kwargs) -> str:
    """Strict JSON (RFC 8259): numpy values converted, NaN/Inf written as null, never as bare NaN/Infinity."""
    return json.dumps(finite_or_none(obj), default=json_default, allow_nan=False, **kwargs)
