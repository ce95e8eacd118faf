"""Node parameters declared from one spec list (flagbot_sim/values.py: the specs and the value checks, without ROS),
so the descriptors, `--help` and msg_docs/ say the same thing.
"""
from __future__ import annotations

from pathlib import Path

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from ..scene import Scene
from ..values import SCENE_PARAMS, ParamSpec, node_scene


def descriptor(spec: ParamSpec):
    """``spec`` as an rcl_interfaces ParameterDescriptor: its description (with the unit), range and choices."""
    d = ParameterDescriptor(description=spec.description + (f" [{spec.unit}]" if spec.unit else ""),
                            read_only=spec.read_only)
    if spec.choices:
        d.additional_constraints = "one of: " + ", ".join(spec.choices)
    if spec.range is not None:
        lo, hi = spec.range
        if isinstance(spec.default, int) and not isinstance(spec.default, bool):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
        else:
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


#: YAML's spellings of true, as rcl reads a ``-p NAME:=VALUE`` value
_TRUE = ("true", "True", "TRUE")


def lifecycle_requested(argv: list[str], node: str = "sim_node") -> bool:
    """Whether ``-p lifecycle:=true`` (or ``--param``, or ``NODE:lifecycle:=true``) is among ``argv``'s
    ``--ros-args`` sections (the last one wins). The node's class is chosen before the node exists, so from the
    command line only; the declared parameter is checked against this choice once it exists."""
    value, in_ros, i = None, False, 0
    while i < len(argv):
        word = argv[i]
        if word == "--ros-args":
            in_ros = True
        elif word == "--":
            in_ros = False
        elif in_ros and word in ("-p", "--param") and i + 1 < len(argv):
            key, sep, val = argv[i + 1].partition(":=")
            if sep and key in ("lifecycle", f"{node}:lifecycle"):
                value = val
            i += 1
        i += 1
    return value in _TRUE


def declare(node, specs: list[ParamSpec]) -> None:
    """Declare every parameter; raises ValueError when a start value is not one of its spec's choices."""
    for s in specs:
        if isinstance(s.default, list):
            # an empty list cannot carry its element type: declare uninitialised, then set a typed []
            node.declare_parameter(s.name, Parameter.Type.STRING_ARRAY, descriptor(s))
            try:
                node.get_parameter(s.name)
            except ParameterUninitializedException:
                node.set_parameters([Parameter(s.name, Parameter.Type.STRING_ARRAY, list(s.default))])
        else:
            node.declare_parameter(s.name, s.default, descriptor(s))
        reason = s.refusal(node.get_parameter(s.name).value)
        if reason:
            raise ValueError(reason)


def help_text(prog: str, summary: str, specs: list[ParamSpec], topics: str = "") -> str:
    lines = [f"usage: {prog} [-h] [--version] [--ros-args -p NAME:=VALUE ...]", "", summary, "",
             "options:", "  -h, --help   show this help message and exit",
             "  --version    print the version of flagbot_sim and exit", "", "parameters:"]
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


def scene_request(node, new: dict) -> Scene | None:
    """The scene the node would run once ``new`` parameter values apply, or None if they leave the scene alone.

    Raises SceneError with the reason when the combination is invalid.
    """
    if not set(SCENE_PARAMS) & set(new):
        return None
    cur = {k: node.get_parameter(k).value for k in SCENE_PARAMS}
    cur.update({k: v for k, v in new.items() if k in cur})
    return node_scene(cur["scene"], cur["n_flagella"], list(cur["scene_overrides"]))
