"""The values a node's parameters may take, without ROS: the parameter specs (:class:`ParamSpec`: type, range,
choices, the help line), the checks a node applies to a value before anything changes (bounded strings without
control characters, frame names, a recording path, a motor command), the scene a node runs (:func:`node_scene`:
scene.py's one loader, which refuses anything other than a readable regular UTF-8 file of sane size without ever
blocking on it, with every failure turned into a :class:`SceneError` with a one-line reason), and the time limit on
work done for a parameter set (:class:`TimeLimited`).

The nodes (flagbot_sim/ros/params.py declares these specs as ROS parameters) and the ROS-free device core
(flagbot_sim/device.py) share them.
"""
from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, TypeVar

from .fields import control_character
from .scene import Scene, SceneError, load_scene
from .topics import node_overrides

MAX_STRING = 4096            # longest accepted string parameter (a path, a scene name, one override)
MAX_OVERRIDES = 64           # most entries in scene_overrides
MAX_FRAME = 256              # longest frame id
#: rclpy's tolerance at a range's ends: a value this close (relative) to an end is inside
RANGE_REL_TOL = 1e-6
T = TypeVar("T")

#: the parameters that together choose a node's scene
SCENE_PARAMS = ("scene", "n_flagella", "scene_overrides")


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: object
    description: str
    unit: str = ""
    range: tuple | None = None          # (low, high) inclusive
    choices: tuple = field(default_factory=tuple)
    read_only: bool = False             # set at start only (rclpy refuses a later set)

    @property
    def type_name(self) -> str:
        if isinstance(self.default, bool):
            return "bool"
        if isinstance(self.default, int):
            return "int"
        if isinstance(self.default, float):
            return "double"
        if isinstance(self.default, list):
            return "string[]"
        return "string"

    def help_line(self) -> str:
        rng = f"  range [{self.range[0]}, {self.range[1]}]" if self.range else ""
        ch = f"  one of {', '.join(self.choices)}" if self.choices else ""
        unit = f" {self.unit}" if self.unit else ""
        return f"  {self.name} ({self.type_name}, default {self.default!r}{unit}){rng}{ch}\n      {self.description}"

    def refusal(self, value) -> str | None:
        """Why ``value`` is refused, or None: not one of ``choices``, or not a number inside ``range`` (NaN never
        is). In a node rclpy enforces the range first, with the same tolerance at the ends (RANGE_REL_TOL); the
        check here serves where no rclpy stands in front (flagbot_sim.device)."""
        if self.choices and value not in self.choices:
            return f"{self.name} = {value!r}: choose one of {', '.join(self.choices)}"
        if self.range is not None:
            lo, hi = self.range
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return f"{self.name} = {one_line(repr(value), 80)}: a number in [{lo}, {hi}] is expected"
            if not (lo <= value <= hi or math.isclose(value, lo, rel_tol=RANGE_REL_TOL)
                    or math.isclose(value, hi, rel_tol=RANGE_REL_TOL)):
                return f"{self.name} = {value!r} is outside its range [{lo}, {hi}]"
        return None


def refusal(specs: list[ParamSpec], new: dict) -> str | None:
    """For a set-parameter callback: why the new values are refused (a value outside its choices or range), or
    None."""
    by_name = {s.name: s for s in specs}
    for name, value in new.items():
        reason = by_name[name].refusal(value) if name in by_name else None
        if reason:
            return reason
    return None


def one_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, at most ``limit`` characters (an error message that echoes a huge value stays short)."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def command_refusal(omega: float, max_omega: float) -> str | None:
    """Why a motor command (cmd_omega, rad/s) is rejected: not finite, or |omega| > max_omega; None if accepted."""
    if not math.isfinite(omega):
        return "not a finite number"
    if abs(omega) > max_omega:
        return f"|omega| exceeds max_omega = {max_omega:g} rad/s"
    return None


def text_refusal(name: str, value, limit: int = MAX_STRING) -> str | None:
    """Why a string parameter value is refused: longer than ``limit``, or holding a control character (a newline,
    a NUL, ...: a name, a path, an override is one line); None if accepted."""
    if isinstance(value, str):
        if len(value) > limit:
            return f"{name} is {len(value)} characters long; at most {limit} are accepted"
        bad = control_character(value)
        if bad:
            return f"{name} = {one_line(repr(value), 120)} holds {bad}: it must be one line of printable text"
    return None


def record_refusal(path: str) -> str | None:
    """Why ``record`` = ``path`` is refused before the recorder opens it (None: the recorder decides): a control
    character (text_refusal), or a symbolic link, at the name given or at the '.mcap' name the writer makes of it,
    whose target does not exist: opening it would create that target, a file of another name, elsewhere. (A link
    to an existing file or directory is refused by the writer, as that file or directory is.)

    A NUL never gets here through ROS: rclpy's string conversion ends the value at its first NUL (in the client,
    on serialisation, and in the node, on deserialisation), so the node receives and records to the part before
    it; this check refuses the NUL for the values that do reach the node whole."""
    reason = text_refusal("record", path)
    if reason or not isinstance(path, str) or not path:
        return reason
    given = Path(path)
    for p in (given, given if given.suffix == ".mcap" else given.with_name(given.name + ".mcap")):
        try:
            dangling = p.is_symlink() and not p.exists()
            target = os.readlink(p) if dangling else ""
        except (OSError, ValueError):        # unreadable: the writer reports it
            continue
        if dangling:
            return (f"record = {one_line(repr(path), 120)}: {one_line(str(p), 120)} is a symbolic link to "
                    f"{one_line(repr(target), 120)}, which does not exist: recording would create that file "
                    "instead; give the file's own name")
    return None


def frame_refusal(name: str, value: str) -> str | None:
    """Why a frame id is refused: empty, longer than MAX_FRAME, or holding whitespace or control characters."""
    if not value.strip():
        return f"{name} must not be empty"
    if len(value) > MAX_FRAME:
        return f"{name} is {len(value)} characters long; at most {MAX_FRAME} are accepted"
    if any(c.isspace() or not c.isprintable() for c in value):
        return f"{name} = {one_line(repr(value), 80)}: a frame id holds no spaces or control characters"
    return None


def node_scene(scene, n_flagella: int, scene_overrides) -> Scene:
    """The scene a node runs: a scene name or file, its overrides, and n_flagella (0 keeps the scene's).

    Any failure is a SceneError with a one-line reason: a value of the wrong shape, a path that is not a readable
    regular file, a file that is not valid TOML or not a valid scene, and anything the scene checks raise
    besides SceneError (they are refused, not passed on as a crash of the node).
    """
    if not isinstance(scene, str) or not scene.strip():
        raise SceneError(f"scene = {scene!r}: name a built-in scene (design1, design2, ...) or a .toml file")
    reason = text_refusal("scene", scene)
    overrides = list(scene_overrides)
    if len(overrides) > MAX_OVERRIDES:
        reason = f"scene_overrides has {len(overrides)} entries; at most {MAX_OVERRIDES} are accepted"
    for o in overrides:
        reason = reason or text_refusal("a scene_overrides entry", o)
    if reason:
        raise SceneError(reason)
    try:
        result = load_scene(scene, node_overrides(n_flagella, overrides))    # the CLI's reading, to the byte
    except SceneError as exc:
        raise SceneError(one_line(str(exc))) from None
    except (RecursionError, MemoryError) as exc:
        raise SceneError(f"scene {one_line(repr(scene), 120)}: too deeply nested or too large "
                         f"({type(exc).__name__})") from None
    except Exception as exc:  # noqa: BLE001 - a scene-check bug must refuse the value, not kill the node
        raise SceneError(one_line(f"scene {scene!r} with overrides {overrides!r} is invalid: "
                                  f"{type(exc).__name__}: {exc}")) from None
    return result


class TimeLimited:
    """Run one piece of work at a time on a worker thread, waiting for it at most ``limit`` seconds.

    For work done inside a set-parameters callback (a scene load and simulation build): the callback cannot be
    answered asynchronously, so a pathological case must not hold the executor longer than the limit. Work that
    overruns is abandoned (its result dropped when it finishes); until then further work is refused.
    """

    def __init__(self, limit: float, what: str):
        self.limit = limit
        self.what = what
        self._thread: threading.Thread | None = None

    def run(self, fn: Callable[[], T]) -> T:
        if self._thread is not None and self._thread.is_alive():
            raise SceneError(f"{self.what} that overran its {self.limit:g} s limit is still running; try later")
        box: dict = {}

        def work():
            try:
                box["value"] = fn()
            except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread
                box["error"] = exc

        t = threading.Thread(target=work, name=self.what.replace(" ", "-"), daemon=True)
        t.start()
        t.join(self.limit)
        if t.is_alive():
            self._thread = t
            raise SceneError(f"{self.what} took longer than {self.limit:g} s; refused")
        if "error" in box:
            raise box["error"]
        return box["value"]
