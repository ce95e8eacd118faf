"""The layers of flagbot_sim (docs/architecture.md), kept by the import graph: every module sits in one layer and
imports only its own layer or the layers below; the physics imports only numeric libraries; bag, the physics and the
libraries import no ROS; nothing but the entry points imports a command; and no import cycle.

The graph is read from the source with ``ast``, not from what happens to be imported at run time, so an import
inside a function counts as much as one at the top (it runs whenever that function does). Relative imports are
resolved, and modules loaded through importlib count as imports of the module that loads them: a constant
``importlib.import_module("...")`` argument (absolute, or relative to the module's package), an f-string
argument whose constant head names a package (``f"flagbot_sim.bench.{name}"``, ``f"{__name__}.{name}"``) joined
with each string constant of the module, and, in a module that calls ``importlib.import_module`` with any other
computed name, every string constant in it that names a flagbot_sim module (``COMMAND_MODULES`` in cli.py is
such a list). ``import_module`` under another name (``from importlib import import_module as load``) is the same
call, and a string constant that names a flagbot_sim module passed to any call is an import of it: that is how a
helper that imports what it is given is used (``optional.require(..., "flagbot_sim.x")``, ``ros_entry("...")``).
ROS libraries are known by name and by ROS 2's package naming (``*_msgs``, ``*_srvs``, ``*_interfaces``, ``tf2_*``,
``rcl*``, ...), and the physics' numeric-only rule holds for everything it loads, the base modules it imports
included. Each rule is also shown to fail on a synthetic violation.
"""
import ast
import sys
from pathlib import Path

import pytest

PACKAGE = "flagbot_sim"
SRC = Path(__file__).resolve().parents[1] / PACKAGE

#: the layers, lowest first: (name, the modules and packages in it). A module imports only its own layer and the
#: ones before it. "flagbot_sim" itself (the version) is the package module alone, not everything under it.
LAYERS = [
    ("base", ["flagbot_sim", "flagbot_sim.world", "flagbot_sim.topics", "flagbot_sim.plotlabels",
              "flagbot_sim.progress", "flagbot_sim.optional", "flagbot_sim.pacer", "flagbot_sim.scenes",
              "flagbot_sim.units", "flagbot_sim.fields", "flagbot_sim.scene_files"]),
    ("physics", ["flagbot_sim.physics", "flagbot_sim.scene", "flagbot_sim.kernels", "flagbot_sim.reference"]),
    ("support", ["flagbot_sim.cliutil", "flagbot_sim.workers", "flagbot_sim.bag", "flagbot_sim.motor_profile", "flagbot_sim.urdf",
                 "flagbot_sim.tf_tree", "flagbot_sim.values"]),
    ("libraries", ["flagbot_sim.beam", "flagbot_sim.sweep", "flagbot_sim.fit", "flagbot_sim.runs",
                   "flagbot_sim.device"]),
    ("adapters", ["flagbot_sim.ros", "flagbot_sim.view", "flagbot_sim.bench"]),
    ("commands", ["flagbot_sim.commands", "flagbot_sim.cli", "flagbot_sim.console", "flagbot_sim.completion",
                  "flagbot_sim.__main__"]),
]
LAYER_NAMES = [name for name, _ in LAYERS]

#: what the physics layer may import besides the standard library and flagbot_sim's own base and physics modules
NUMERIC = {"numpy", "scipy", "numba", "llvmlite"}
#: ROS 2's Python libraries and message packages (by top-level name)
ROS = {"rclpy", "rosidl_runtime_py", "rosidl_parser", "rpyutils", "rosbag2_py", "rclpy_message_converter",
       "std_msgs", "geometry_msgs", "sensor_msgs", "nav_msgs", "visualization_msgs", "rosgraph_msgs",
       "diagnostic_msgs", "std_srvs", "tf2_msgs", "builtin_interfaces", "rcl_interfaces", "lifecycle_msgs",
       "launch", "launch_ros"}
#: ROS 2 package names by their conventions: message/service/action packages and the client, transport, tf and
#: launch libraries (rclpy_lifecycle, tf2_ros, action_msgs, rmw_*, ros2cli, ...)
ROS_SUFFIXES = ("_msgs", "_srvs", "_interfaces", "_actions")
ROS_PREFIXES = ("rcl", "rmw", "rosidl", "rosbag2", "ros2", "tf2", "launch", "message_filters")
# (ament_index_python is not among them: a file lookup, no ROS runtime; bag.schema finds .msg files with it where
# a ROS prefix is set, as rosbag2 does, and reads them from the package's own copies elsewhere)
#: layers that import no ROS library: ROS 2 is an optional extra, loaded only by the adapters and commands
ROS_FREE = {"base", "physics", "support", "libraries"}
#: layers that know nothing of command lines: argparse belongs to the commands (and the adapters' own scripts)
ARGPARSE_FREE = {"physics", "libraries"}
#: what the base layer may import besides the standard library (docs/architecture.md)
BASE_EXTERNAL = {"numpy", "scipy", "matplotlib"}


def is_ros(name: str) -> bool:
    """Whether the top-level module ``name`` is a ROS 2 library or message package."""
    return name in ROS or name.endswith(ROS_SUFFIXES) or name.startswith(ROS_PREFIXES)


def module_names(src: Path = SRC) -> dict[str, Path]:
    """Dotted name -> file of every module and package of flagbot_sim."""
    out = {}
    for f in sorted(src.rglob("*.py")):
        parts = list(f.relative_to(src.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = f
    return out


def _package_of(module: str, is_package: bool) -> list[str]:
    return module.split(".") if is_package else module.split(".")[:-1]


def _resolve_from(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = _package_of(module, is_package)
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_import_module_call(node: ast.AST, aliases: frozenset = frozenset()) -> bool:
    """``importlib.import_module(...)``, ``import_module(...)``, ``__import__(...)``, or a call of a name
    ``import_module`` was imported as (``aliases``)."""
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return (isinstance(f, ast.Attribute) and f.attr == "import_module") or (
        isinstance(f, ast.Name) and f.id in {"import_module", "__import__", *aliases})


def _import_module_aliases(tree: ast.AST) -> frozenset:
    """The names ``from importlib import import_module as NAME`` binds in a module."""
    return frozenset(a.asname for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module == "importlib"
                     for a in n.names if a.name == "import_module" and a.asname)


def _fstring_head(node: ast.JoinedStr, module: str, is_package: bool) -> str | None:
    """The constant start of an f-string module name: its leading constants, with ``{__name__}`` and
    ``{__package__}`` read as the module's own names; None when it starts with anything else."""
    head = ""
    for part in node.values:
        if isinstance(part, ast.Constant) and isinstance(part.value, str):
            head += part.value
        elif isinstance(part, ast.FormattedValue) and isinstance(part.value, ast.Name) and \
                part.value.id in ("__name__", "__package__") and not head:
            head += module if part.value.id == "__name__" else ".".join(_package_of(module, is_package))
        else:
            break
    return head or None


def parse_imports(module: str, source: str, modules, is_package: bool = False) -> tuple[set[str], set[str]]:
    """(flagbot_sim modules, top-level names of other modules) that ``module``, whose text is ``source``,
    imports anywhere; ``modules`` are the names of flagbot_sim's modules."""
    tree = ast.parse(source)
    found: set[str] = set()
    external: set[str] = set()
    strings = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)}

    def add(name: str) -> None:
        if not name:
            return
        if name.split(".")[0] != PACKAGE:
            external.add(name.split(".")[0])
            return
        # `import a.b.c` binds a, but loads a.b.c: the deepest existing module is the dependency
        while name and name not in modules:
            name = name.rpartition(".")[0]
        if name.startswith(PACKAGE) and name != module:
            found.add(name)

    dynamic = False
    aliases = _import_module_aliases(tree)
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and not _is_import_module_call(node, aliases):
            # a module's name handed to a helper that imports it (import_module's own arguments: below)
            for arg in [*node.args, *(k.value for k in node.keywords)]:
                if isinstance(arg, ast.Constant) and isinstance(arg.value, str) and arg.value in modules:
                    add(arg.value)
        if isinstance(node, ast.Import):
            for a in node.names:
                add(a.name)
        elif isinstance(node, ast.ImportFrom):
            target = _resolve_from(module, is_package, node)
            if node.level == 0 and not target.startswith(PACKAGE):
                add(target)
                continue
            for a in node.names:
                sub = f"{target}.{a.name}"
                add(sub if sub in modules else target)   # `from pkg import submodule` imports the submodule
        elif _is_import_module_call(node, aliases):
            arg = node.args[0] if node.args else None
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                name = arg.value
                if name.startswith("."):                 # import_module(".x", "pkg") or (".x", __package__)
                    level = len(name) - len(name.lstrip("."))
                    pkg = node.args[1] if len(node.args) > 1 else None
                    base = (pkg.value.split(".") if isinstance(pkg, ast.Constant) and isinstance(pkg.value, str)
                            else _package_of(module, is_package))
                    name = ".".join(base[: len(base) - (level - 1)] + [name.lstrip(".")])
                add(name)
            elif isinstance(arg, ast.JoinedStr) and (head := _fstring_head(arg, module, is_package)):
                for s in strings:
                    if head + s in modules:
                        add(head + s)
            else:
                dynamic = True
    if dynamic:
        for s in strings:
            if s in modules:
                add(s)
    return found, external


def imports_of(module: str, path: Path, modules) -> set[str]:
    """flagbot_sim modules that ``module`` imports, anywhere in its source."""
    return parse_imports(module, path.read_text(), modules, path.name == "__init__.py")[0]


def external_imports_of(module: str, path: Path, modules) -> set[str]:
    """Top-level names of the non-flagbot_sim modules that ``module`` imports, anywhere in its source."""
    return parse_imports(module, path.read_text(), modules, path.name == "__init__.py")[1]


def import_graph() -> dict[str, set[str]]:
    modules = module_names()
    return {m: imports_of(m, p, modules) for m, p in modules.items()}


def layer_of(module: str) -> str | None:
    """The layer whose longest entry is ``module`` or a package holding it (``flagbot_sim`` itself only by name)."""
    best, best_len = None, -1
    for name, entries in LAYERS:
        for e in entries:
            if (module == e or (e != PACKAGE and module.startswith(e + "."))) and len(e) > best_len:
                best, best_len = name, len(e)
    return best


def layer_violations(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a module in a higher layer than the importer's (or of or by a module in no layer)."""
    rank = {name: k for k, name in enumerate(LAYER_NAMES)}
    out = []
    for module, deps in sorted(graph.items()):
        lm = layer_of(module)
        for d in sorted(deps):
            ld = layer_of(d)
            if lm is None or ld is None or rank[ld] > rank[lm]:
                out.append(f"{module} ({lm}) imports {d} ({ld})")
    return out


def external_violations(module: str, external: set[str]) -> list[str]:
    """The non-flagbot_sim imports ``module``'s layer does not allow: beyond the standard library and
    :data:`NUMERIC` for the physics, beyond it and :data:`BASE_EXTERNAL` for the base, any ROS library for the
    ROS-free layers."""
    layer = layer_of(module)
    bad = set()
    if layer == "physics":
        bad |= {e for e in external if e not in sys.stdlib_module_names and e not in NUMERIC}
    if layer == "base":
        bad |= {e for e in external if e not in sys.stdlib_module_names and e not in BASE_EXTERNAL}
    if layer in ROS_FREE:
        bad |= {e for e in external if is_ros(e)}
    if layer in ARGPARSE_FREE:
        bad |= {e for e in external if e == "argparse"}
    return [f"{module} ({layer}) imports {e}" for e in sorted(bad)]


def loaded_external_violations(graph: dict[str, set[str]], external: dict[str, set[str]]) -> list[str]:
    """The physics' numeric-only rule over everything a physics module loads: the non-numeric, non-standard
    imports of the flagbot_sim modules it imports, directly or through others (a base module's matplotlib)."""
    out = []
    for module in sorted(graph):
        if layer_of(module) != "physics":
            continue
        seen, todo = set(), [module]
        while todo:
            for d in graph.get(todo.pop(), ()):
                if d not in seen:
                    seen.add(d)
                    todo.append(d)
        for d in sorted(seen):
            for e in sorted(external.get(d, ())):
                if e not in sys.stdlib_module_names and e not in NUMERIC:
                    out.append(f"{module} (physics) loads {e} through {d}")
    return out


def components(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module: each is a set of modules that import one
    another in a circle (Tarjan's algorithm, iterative)."""
    index, low, on_stack, stack, comps = {}, {}, set(), [], []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            w = next(it, None)
            if w is not None:
                if w not in graph:
                    continue
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    comps.append(sorted(comp))
    return comps


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """One cycle per component, as a path that returns to its start (a shortest one through its first module)."""
    out = []
    for comp in components(graph):
        members, start = set(comp), comp[0]
        prev, frontier, path = {start: None}, [start], None
        while frontier and path is None:      # breadth first inside the component, until an edge back to start
            nxt = []
            for v in frontier:
                if start in graph[v]:
                    path = [v]
                    while prev[path[-1]] is not None:
                        path.append(prev[path[-1]])
                    path = path[::-1] + [start]
                    break
                for w in sorted(graph[v] & members):
                    if w not in prev:
                        prev[w] = v
                        nxt.append(w)
            frontier = nxt
        out.append(path)
    return out


# ------------------------------------------------------------------------------------------------ the parser
def test_the_graph_sees_the_imports_that_matter():
    """Guards the parser itself: a relative import, an import inside a function, `from . import submodule`, and
    the modules loaded through importlib (a computed name in cli.py and console.py, f-strings in the physics
    package and the bench command) are all edges."""
    g = import_graph()
    assert "flagbot_sim.bag.writer" in g["flagbot_sim.bag"]                  # from .writer import BagWriter
    assert "flagbot_sim.ros.recorder" in g["flagbot_sim.commands.record"]    # inside cmd_record
    assert "flagbot_sim.physics.warmup" in g["flagbot_sim.physics.simulation"]   # from . import warmup
    assert {"flagbot_sim.commands.replay", "flagbot_sim.commands.sweep",
            "flagbot_sim.commands.beam"} <= g["flagbot_sim.cli"]              # COMMAND_MODULES, by name
    assert "flagbot_sim.commands.replay" in g["flagbot_sim.console"]         # ros_entry("...", ...)
    assert "flagbot_sim.physics.simulation" in g["flagbot_sim.physics"]      # f"{__name__}.{_EXPORTS[name]}"
    assert "flagbot_sim.bench.accuracy" in g["flagbot_sim.commands.bench"]   # f"flagbot_sim.bench.{module}"


def test_the_parser_reads_every_kind_of_import():
    modules = {"flagbot_sim", "flagbot_sim.ros", "flagbot_sim.ros.sim_node", "flagbot_sim.physics",
               "flagbot_sim.physics.model", "flagbot_sim.physics.fake", "flagbot_sim.commands",
               "flagbot_sim.commands.run", "flagbot_sim.view", "flagbot_sim.view.live"}
    source = "\n".join([
        "import os.path, numpy as np",
        "from .model import RobotModel",                       # relative, in the package
        "from .. import commands",                             # the package, from two levels
        "def f():",
        "    import importlib",
        "    from rclpy.node import Node",
        "    importlib.import_module('flagbot_sim.ros.sim_node')",
        "    importlib.import_module('.live', 'flagbot_sim.view')",
        "    return importlib.import_module(f'flagbot_sim.commands.{NAME}')",
        "NAME = 'run'",
    ])
    found, external = parse_imports("flagbot_sim.physics.fake", source, modules)
    assert found == {"flagbot_sim.physics.model", "flagbot_sim.commands", "flagbot_sim.ros.sim_node",
                     "flagbot_sim.view.live", "flagbot_sim.commands.run"}
    assert external == {"os", "numpy", "rclpy", "importlib"}


def test_an_aliased_import_module_and_a_module_name_given_to_a_helper_are_imports():
    modules = {"flagbot_sim", "flagbot_sim.ros", "flagbot_sim.ros.fake", "flagbot_sim.commands",
               "flagbot_sim.commands.run", "flagbot_sim.commands.render", "flagbot_sim.optional"}
    source = "\n".join([
        "from importlib import import_module as load",
        "from ..optional import require",
        "def f(name):",
        "    load(name)",
        "    return require('view', 'the view', module='flagbot_sim.commands.render')",
        "TARGET = 'flagbot_sim.commands.run'",          # found because load() takes a computed name
        "DOC = 'see flagbot_sim.commands for the commands'",  # prose, not a module name: no edge
    ])
    found, _ = parse_imports("flagbot_sim.ros.fake", source, modules)
    assert found == {"flagbot_sim.optional", "flagbot_sim.commands.run", "flagbot_sim.commands.render"}


def test_a_cycle_is_found_and_printed_as_a_path():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


# ------------------------------------------------------------------------------------------------ the rules
def test_every_module_has_a_layer():
    """A new module must be placed in a layer here (and in docs/architecture.md) before the rules can hold."""
    unplaced = sorted(m for m in module_names() if layer_of(m) is None)
    assert not unplaced, f"modules in no layer (add them to LAYERS and docs/architecture.md): {unplaced}"


def test_imports_point_down_the_layers():
    """physics -> nothing above it; bag -> no command; ros/, view/ -> no command; nothing but the entry points
    (cli, console, completion, commands/) imports a command."""
    bad = layer_violations(import_graph())
    assert not bad, "imports against the layers (docs/architecture.md):\n  " + "\n  ".join(bad)


def test_the_layer_rules_fail_on_a_violation():
    assert layer_violations({"flagbot_sim.physics.model": {"flagbot_sim.ros.sim_node"}}) == [
        "flagbot_sim.physics.model (physics) imports flagbot_sim.ros.sim_node (adapters)"]
    assert layer_violations({"flagbot_sim.view.render": {"flagbot_sim.commands.render"},
                             "flagbot_sim.ros.replay": {"flagbot_sim.commands.replay"},
                             "flagbot_sim.bag.reader": {"flagbot_sim.cli"}}) == [
        "flagbot_sim.bag.reader (support) imports flagbot_sim.cli (commands)",
        "flagbot_sim.ros.replay (adapters) imports flagbot_sim.commands.replay (commands)",
        "flagbot_sim.view.render (adapters) imports flagbot_sim.commands.render (commands)"]
    assert layer_violations({"flagbot_sim.newthing": {"flagbot_sim.scene"}}) == [
        "flagbot_sim.newthing (None) imports flagbot_sim.scene (physics)"]
    # sideways and down are allowed: a command uses a library, the view a library, the physics the scene
    assert layer_violations({"flagbot_sim.commands.replay": {"flagbot_sim.runs.resim", "flagbot_sim.ros.replay"},
                             "flagbot_sim.view.recorded": {"flagbot_sim.runs.resim"},
                             "flagbot_sim.physics.warmup": {"flagbot_sim.scene"}}) == []
    assert layer_of("flagbot_sim") == "base" and layer_of("flagbot_sim.physics.model") == "physics"
    assert layer_of("flagbot_sim.unknown") is None      # "flagbot_sim" holds the package module only


def test_the_physics_imports_only_numeric_libraries_and_no_layer_below_the_adapters_imports_ros():
    modules = module_names()
    bad = [v for m, p in modules.items() for v in external_violations(m, external_imports_of(m, p, modules))]
    assert not bad, "imports the layer does not allow (docs/architecture.md):\n  " + "\n  ".join(bad)


def test_the_library_rules_fail_on_a_violation():
    modules = set(module_names())
    _, ext = parse_imports("flagbot_sim.physics.fake", "import math\nimport numba\nfrom matplotlib import pyplot\n"
                           "def f():\n    import rclpy\n", modules)
    assert external_violations("flagbot_sim.physics.fake", ext) == [
        "flagbot_sim.physics.fake (physics) imports matplotlib", "flagbot_sim.physics.fake (physics) imports rclpy"]
    _, ext = parse_imports("flagbot_sim.bag.fake", "import zstandard\nfrom std_msgs.msg import Float64\n", modules)
    assert external_violations("flagbot_sim.bag.fake", ext) == ["flagbot_sim.bag.fake (support) imports std_msgs"]
    _, ext = parse_imports("flagbot_sim.ros.fake", "import rclpy\n", modules)
    assert external_violations("flagbot_sim.ros.fake", ext) == []
    # a library knows no command line (beam/timing.py was an argparse script among the libraries)
    _, ext = parse_imports("flagbot_sim.beam.fake", "import argparse\n", modules)
    assert external_violations("flagbot_sim.beam.fake", ext) == ["flagbot_sim.beam.fake (libraries) imports argparse"]
    # ROS 2 packages that are not in the list, known by their names' conventions
    _, ext = parse_imports("flagbot_sim.device", "def f():\n    import tf2_ros\n    from action_msgs.msg import G\n"
                           "    import rclpy_message_converter, example_interfaces, rmw_fastrtps_cpp\n", modules)
    assert external_violations("flagbot_sim.device", ext) == [
        f"flagbot_sim.device (libraries) imports {e}" for e in
        ("action_msgs", "example_interfaces", "rclpy_message_converter", "rmw_fastrtps_cpp", "tf2_ros")]
    # the base: the standard library, numpy, scipy, matplotlib
    _, ext = parse_imports("flagbot_sim.units", "import json, numpy, matplotlib\nimport mcap\n", modules)
    assert external_violations("flagbot_sim.units", ext) == ["flagbot_sim.units (base) imports mcap"]
    # the physics through a base module it imports
    graph = {"flagbot_sim.physics.model": {"flagbot_sim.plotlabels"}, "flagbot_sim.plotlabels": set(),
             "flagbot_sim.physics.frames": {"flagbot_sim.units"}, "flagbot_sim.units": set()}
    external = {"flagbot_sim.physics.model": {"numpy"}, "flagbot_sim.plotlabels": {"matplotlib", "math"},
                "flagbot_sim.physics.frames": {"numba"}, "flagbot_sim.units": {"math"}}
    assert loaded_external_violations(graph, external) == [
        "flagbot_sim.physics.model (physics) loads matplotlib through flagbot_sim.plotlabels"]


def test_the_physics_loads_only_numeric_libraries_through_what_it_imports():
    modules = module_names()
    external = {m: external_imports_of(m, p, modules) for m, p in modules.items()}
    bad = loaded_external_violations(import_graph(), external)
    assert not bad, "the physics loads what it may not (docs/architecture.md):\n  " + "\n  ".join(bad)


def test_no_import_cycle():
    g = import_graph()
    found = [(" -> ".join(c), ", ".join(comp)) for c, comp in zip(cycles(g), components(g))]
    assert not found, "import cycles:\n" + "\n".join(f"  {c}   (all in this circle: {comp})" for c, comp in found)


@pytest.mark.parametrize("forbidden", ["flagbot_sim.cli", "flagbot_sim.commands", "flagbot_sim.topics",
                                       "flagbot_sim.ros", "flagbot_sim.runs", "flagbot_sim.physics",
                                       "flagbot_sim.scene"])
def test_the_bag_package_knows_no_cli_no_ros_and_no_flagbot_topic(forbidden):
    """Within its layer too, bag stands alone: callers pass topic names in, and it needs no scene or physics."""
    g = import_graph()
    for module, deps in g.items():
        if module == "flagbot_sim.bag" or module.startswith("flagbot_sim.bag."):
            bad = {d for d in deps if d == forbidden or d.startswith(forbidden + ".")}
            assert not bad, f"{module} imports {sorted(bad)}"
