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
such a list). Each rule is also shown to fail on a synthetic violation.
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
    ("support", ["flagbot_sim.cliutil", "flagbot_sim.bag", "flagbot_sim.motor_profile", "flagbot_sim.urdf",
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
# (ament_index_python is not among them: a file lookup, no ROS runtime; bag.schema finds .msg files with it where
# a ROS prefix is set, as rosbag2 does, and reads them from the package's own copies elsewhere)
#: layers that import no ROS library: ROS 2 is an optional extra, loaded only by the adapters and commands
ROS_FREE = {"base", "physics", "support", "libraries"}


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


def _is_import_module_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return (isinstance(f, ast.Attribute) and f.attr == "import_module") or (isinstance(f, ast.Name) and
                                                                             f.id in ("import_module", "__import__"))


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
    for node in ast.walk(tree):
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
        elif _is_import_module_call(node):
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
    :data:`NUMERIC` for the physics, any ROS library for the ROS-free layers."""
    layer = layer_of(module)
    bad = set()
    if layer == "physics":
        bad |= {e for e in external if e not in sys.stdlib_module_names and e not in NUMERIC}
    if layer in ROS_FREE:
        bad |= external & ROS
    return [f"{module} ({layer}) imports {e}" for e in sorted(bad)]


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
