"""The modules of flagbot_sim import one another one way: no import cycle, and the bag package stays a library.

The graph is read from the source with ``ast``, not from what happens to be imported at run time, so an import
inside a function counts as much as one at the top (it runs whenever that function does). Modules loaded through
importlib count as imports of the module that loads them: a constant ``importlib.import_module("...")`` argument,
and, in a module that calls ``importlib.import_module`` with a computed name, every string constant in it that
names a flagbot_sim module (``COMMAND_MODULES`` in cli.py is such a list).
"""
import ast
from pathlib import Path

import pytest

PACKAGE = "flagbot_sim"
SRC = Path(__file__).resolve().parents[1] / PACKAGE


def module_names() -> dict[str, Path]:
    """Dotted name -> file of every module and package of flagbot_sim."""
    out = {}
    for f in sorted(SRC.rglob("*.py")):
        parts = list(f.relative_to(SRC.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = f
    return out


def _resolve_from(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _is_import_module_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    f = node.func
    return (isinstance(f, ast.Attribute) and f.attr == "import_module") or (isinstance(f, ast.Name) and
                                                                             f.id in ("import_module", "__import__"))


def imports_of(module: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """flagbot_sim modules that ``module`` imports, anywhere in its source."""
    tree = ast.parse(path.read_text(), str(path))
    is_package = path.name == "__init__.py"
    found: set[str] = set()

    def add(name: str) -> None:
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
            for a in node.names:
                sub = f"{target}.{a.name}"
                add(sub if sub in modules else target)   # `from pkg import submodule` imports the submodule
        elif _is_import_module_call(node):
            arg = node.args[0] if node.args else None
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                add(arg.value)
            else:
                dynamic = True
    if dynamic:
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value in modules:
                add(node.value)
    return found


def import_graph() -> dict[str, set[str]]:
    modules = module_names()
    return {m: imports_of(m, p, modules) for m, p in modules.items()}


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


def test_the_graph_sees_the_imports_that_matter():
    """Guards the parser itself: a relative import, an import inside a function, `from . import submodule`, and
    the command modules cli.py loads through importlib are all edges."""
    g = import_graph()
    assert "flagbot_sim.bag.writer" in g["flagbot_sim.bag"]                 # from .writer import BagWriter
    assert "flagbot_sim.ros.recorder" in g["flagbot_sim.commands.record"]   # inside cmd_record
    assert "flagbot_sim.physics.warmup" in g["flagbot_sim.physics.simulation"]   # from . import warmup
    assert {"flagbot_sim.commands.replay", "flagbot_sim.commands.sweep",
            "flagbot_sim.commands.beam"} <= g["flagbot_sim.cli"]
    # a cycle is found and printed as a path back to its start
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c", "a"]]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    g = import_graph()
    found = [(" -> ".join(c), ", ".join(comp)) for c, comp in zip(cycles(g), components(g))]
    assert not found, "import cycles:\n" + "\n".join(f"  {c}   (all in this circle: {comp})" for c, comp in found)


@pytest.mark.parametrize("forbidden", ["flagbot_sim.cli", "flagbot_sim.commands", "flagbot_sim.topics",
                                       "flagbot_sim.ros", "flagbot_sim.runs", "flagbot_sim.physics",
                                       "flagbot_sim.scene"])
def test_the_bag_package_knows_no_cli_no_ros_and_no_flagbot_topic(forbidden):
    g = import_graph()
    for module, deps in g.items():
        if module == "flagbot_sim.bag" or module.startswith("flagbot_sim.bag."):
            bad = {d for d in deps if d == forbidden or d.startswith(forbidden + ".")}
            assert not bad, f"{module} imports {sorted(bad)}"


def test_the_bag_package_imports_no_ros_library():
    for f in (SRC / "bag").glob("*.py"):
        tree = ast.parse(f.read_text())
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        names |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.level == 0}
        assert not {n for n in names if n.split(".")[0] in ("rclpy", "rosidl_runtime_py")}, f
