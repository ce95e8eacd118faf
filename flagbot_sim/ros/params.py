"""Node parameters declared from one spec list, so the descriptors, `--help` and msg_docs/ say the same thing."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from ..scene import Scene, load_scene, node_overrides

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

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(description=self.description + (f" [{self.unit}]" if self.unit else ""))
        if self.choices:
            d.additional_constraints = "one of: " + ", ".join(self.choices)
        if self.range is not None:
            lo, hi = self.range
            if isinstance(self.default, int) and not isinstance(self.default, bool):
                d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
            else:
                d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
        return d

    def help_line(self) -> str:
        rng = f"  range [{self.range[0]}, {self.range[1]}]" if self.range else ""
        ch = f"  one of {', '.join(self.choices)}" if self.choices else ""
        unit = f" {self.unit}" if self.unit else ""
        return f"  {self.name} ({self.type_name}, default {self.default!r}{unit}){rng}{ch}\n      {self.description}"

    def refusal(self, value) -> str | None:
        """Why ``value`` is refused, or None. Only ``choices`` are checked here: rclpy enforces ``range``."""
        if self.choices and value not in self.choices:
            return f"{self.name} = {value!r}: choose one of {', '.join(self.choices)}"
        return None


def declare(node, specs: list[ParamSpec]) -> None:
    """Declare every parameter; raises ValueError when a start value is not one of its spec's choices."""
    for s in specs:
        if isinstance(s.default, list):
            # an empty list cannot carry its element type: declare uninitialised, then set a typed []
            node.declare_parameter(s.name, Parameter.Type.STRING_ARRAY, s.descriptor())
            try:
                node.get_parameter(s.name)
            except ParameterUninitializedException:
                node.set_parameters([Parameter(s.name, Parameter.Type.STRING_ARRAY, list(s.default))])
        else:
            node.declare_parameter(s.name, s.default, s.descriptor())
        reason = s.refusal(node.get_parameter(s.name).value)
        if reason:
            raise ValueError(reason)


def refusal(specs: list[ParamSpec], new: dict) -> str | None:
    """For a set-parameter callback: why the new values are refused (a value outside its choices), or None."""
    by_name = {s.name: s for s in specs}
    for name, value in new.items():
        reason = by_name[name].refusal(value) if name in by_name else None
        if reason:
            return reason
    return None


def command_refusal(omega: float, max_omega: float) -> str | None:
    """Why a motor command (cmd_omega, rad/s) is rejected: not finite, or |omega| > max_omega; None if accepted."""
    if not math.isfinite(omega):
        return "not a finite number"
    if abs(omega) > max_omega:
        return f"|omega| exceeds max_omega = {max_omega:g} rad/s"
    return None


def help_text(prog: str, summary: str, specs: list[ParamSpec], topics: str = "") -> str:
    lines = [f"usage: {prog} [--ros-args -p NAME:=VALUE ...]", "", summary, "", "parameters:"]
    lines += [s.help_line() for s in specs]
    if topics:
        lines += ["", topics]
    lines += ["", f"Full interface (topics, units, frames, QoS, services): {msg_docs_dir()}/"]
    return "\n".join(lines)


def msg_docs_dir() -> Path:
    """msg_docs/ beside a source checkout, else where setup.py installs it: <prefix>/share/flagbot_sim/msg_docs
    (the package itself sits in <prefix>/lib/pythonX.Y/site-packages/flagbot_sim, for pip and colcon alike)."""
    pkg = Path(__file__).resolve().parents[1]
    src = pkg.parent / "msg_docs"
    return src if src.is_dir() else pkg.parents[3] / "share" / "flagbot_sim" / "msg_docs"


def node_scene(scene: str, n_flagella: int, scene_overrides) -> Scene:
    """The scene a node runs: a scene name or file, its overrides, and n_flagella (0 keeps the scene's)."""
    return load_scene(scene, node_overrides(n_flagella, scene_overrides))


def scene_request(node, new: dict) -> Scene | None:
    """The scene the node would run once ``new`` parameter values apply, or None if they leave the scene alone.

    Raises SceneError (or ValueError) with the reason when the combination is invalid.
    """
    if not set(SCENE_PARAMS) & set(new):
        return None
    cur = {k: node.get_parameter(k).value for k in SCENE_PARAMS}
    cur.update({k: v for k, v in new.items() if k in cur})
    return node_scene(cur["scene"], cur["n_flagella"], list(cur["scene_overrides"]))
