"""The package installs as ROS expects and declares what it imports.

Installed with pip into a prefix: indexed through ament, executables in lib/flagbot_sim/ (ros2 run) that run the
interpreter the package was installed with, console scripts in bin/, msg_docs/, the launch file and the URDFs in
share/. Declared: every third-party import in install_requires or an extra, every runtime dependency in
package.xml by its rosdep key, and the launch file names only executables, parameters and types that exist.
(The end-to-end install into a fresh venv is tests/test_install_venv.py.)
"""
import ast
import os
import re
import subprocess
import sys
import sysconfig
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from install_helpers import EXECUTABLES, PACKAGE, ROOT, copy_sources, fake_python3, ros2_run_path, setup_literal

from flagbot_sim import optional

# third-party top-level module -> (distribution that provides it, extra it belongs to; None = install_requires)
MODULES = {
    "numpy": ("numpy", None), "scipy": ("scipy", None), "numba": ("numba", None), "llvmlite": ("llvmlite", None),
    "mcap": ("mcap", None),
    "mcap_ros2": ("mcap-ros2-support", None), "zstandard": ("zstandard", None), "lz4": ("lz4", None),
    "matplotlib": ("matplotlib", None),
    "dask": ("dask", "dask"), "distributed": ("dask", "dask"),      # dask[distributed] brings both
    "elastica": ("pyelastica", "bench"), "foxglove": ("foxglove-sdk", "view"),
    **{m: ("ros-jazzy-rclpy", "ros") for m in optional.ROS_MODULES},
}
# distribution -> its rosdep key in package.xml; mcap, zstandard and lz4 come through pip with mcap-ros2-support,
# llvmlite with python3-numba (apt's numba depends on python3-llvmlite)
ROSDEP_KEYS = {"numpy": "python3-numpy", "scipy": "python3-scipy", "matplotlib": "python3-matplotlib",
               "numba": "python3-numba", "mcap-ros2-support": "mcap-ros2-support", "mcap": None,
               "zstandard": None, "lz4": None, "llvmlite": None}


def third_party_imports() -> dict[str, set[str]]:
    """Top-level module -> the files of flagbot_sim that import it (absolute imports outside the stdlib)."""
    found: dict[str, set[str]] = {}
    for path in sorted((ROOT / PACKAGE).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top != PACKAGE:
                    found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    return found


def requirement_name(req: str) -> str:
    return re.split(r"[\[<>=!~; ]", req, maxsplit=1)[0].lower()


def test_every_third_party_import_is_declared_for_pip():
    install_requires = {requirement_name(r) for r in setup_literal("INSTALL_REQUIRES")}
    extras = {k: {requirement_name(r) for r in v} for k, v in setup_literal("EXTRAS_REQUIRE").items()}
    imports = third_party_imports()
    unknown = {m: sorted(files) for m, files in imports.items() if m not in MODULES}
    assert not unknown, f"imported but not declared anywhere (add to setup.py and MODULES here): {unknown}"
    for module in imports:
        dist, extra = MODULES[module]
        where = install_requires if extra is None else extras[extra]
        assert dist in where, f"{module} ({dist}) must be in {'install_requires' if extra is None else extra}"
    # numba is required: the numpy twins of the kernels are gone (NUMBA_DISABLE_JIT=1 is the debugging path)
    assert "numba" in install_requires
    # nothing declared that nothing imports
    used = {MODULES[m][0] for m in imports if MODULES[m][1] is None}
    assert install_requires == used, f"declared but not imported: {install_requires - used}"


def test_extras_match_optional_and_the_requirement_files():
    extras = setup_literal("EXTRAS_REQUIRE")
    assert set(extras) == set(optional.EXTRAS)
    for extra, (module, _, _) in optional.EXTRAS.items():
        assert MODULES[module][1] == extra, f"optional.EXTRAS[{extra!r}] marker {module!r} is not that extra's"
    # the dev environment (dev.py: requirements-test.txt -> requirements.txt) has everything but the benchmark
    dev = {requirement_name(r) for r in (ROOT / "requirements.txt").read_text().splitlines()
           if r.strip() and not r.startswith(("#", "-r"))}
    needed = {requirement_name(r) for r in setup_literal("INSTALL_REQUIRES") + extras["ros"] + extras["dask"]}
    assert needed <= dev, f"missing from requirements.txt: {needed - dev}"
    bench = {requirement_name(r) for r in (ROOT / "requirements-bench.txt").read_text().splitlines()
             if r.strip() and not r.startswith(("#", "-r"))}
    assert {requirement_name(r) for r in extras["bench"]} <= bench


def test_package_xml_declares_every_runtime_dependency_by_its_rosdep_key():
    root = ET.parse(ROOT / "package.xml").getroot()
    exec_depends = [e.text.strip() for e in root.iter("exec_depend")]
    assert len(exec_depends) == len(set(exec_depends)), "a key is listed twice"
    imports = third_party_imports()
    expected = {m for m in imports if m in optional.ROS_MODULES}            # ROS package = module name
    expected |= {ROSDEP_KEYS[MODULES[m][0]] for m in imports if MODULES[m][1] is None} - {None}
    assert set(exec_depends) == expected, (f"missing: {sorted(expected - set(exec_depends))}, "
                                           f"not imported: {sorted(set(exec_depends) - expected)}")
    import flagbot_sim
    assert root.findtext("version") == flagbot_sim.__version__
    assert root.find("export/build_type").text == "ament_python"


# ------------------------------------------------------------------------------------- installed into a prefix
@pytest.fixture(scope="module")
def prefix(tmp_path_factory):
    prefix = tmp_path_factory.mktemp("install")
    src = copy_sources(tmp_path_factory.mktemp("src") / PACKAGE)
    # --ignore-installed: without it pip first uninstalls the copy in the running environment (the developer's
    # editable install), as the prefix is not a separate environment to it
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--no-compile", "--ignore-installed", "--prefix", str(prefix), str(src)], check=True,
                   cwd=tmp_path_factory.getbasetemp())
    return prefix


def site_packages(prefix: Path) -> str:
    return sysconfig.get_path("purelib", vars={"base": str(prefix), "platbase": str(prefix)})


def test_package_is_indexed_and_its_share_is_complete(prefix, monkeypatch):
    from ament_index_python.packages import get_package_prefix, get_package_share_directory
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    assert Path(get_package_prefix(PACKAGE)) == prefix
    share = Path(get_package_share_directory(PACKAGE))
    assert (share / "package.xml").read_text() == (ROOT / "package.xml").read_text()
    assert {p.name for p in (share / "scenes").iterdir()} >= {"design1.toml", "design2.toml",
                                                             "clamped_flagellum.toml"}
    for folder, pattern in (("msg_docs", "*.md"), ("launch", "*.py"), ("urdf", "*.urdf")):
        wanted = {p.name: p.read_bytes() for p in (ROOT / folder).glob(pattern)}
        got = {p.name: p.read_bytes() for p in (share / folder).glob(pattern)} if (share / folder).is_dir() else {}
        assert got == wanted, f"share/{PACKAGE}/{folder} differs from the checkout's {folder}/"
    assert "sim_node.md" in {p.name for p in (share / "msg_docs").iterdir()}
    assert (share / "launch" / "flagbot.launch.py").is_file()


def test_wrappers_and_console_scripts_match_setup():
    assert sorted(p.name for p in (ROOT / "scripts").iterdir()) == sorted(EXECUTABLES)


@pytest.mark.parametrize("exe", EXECUTABLES)
def test_ros2_run_executables_run_the_installing_python_not_path_python3(prefix, exe, tmp_path):
    # the prefix has no ROS of its own: the test's environment (its ROS wheels) stays, plus the prefix's
    # site-packages, and a python3 first on PATH that is not the one the package was installed with
    env = dict(os.environ, AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=site_packages(prefix),
               PATH=f"{fake_python3(tmp_path / 'fake')}{os.pathsep}{os.environ['PATH']}")
    path = ros2_run_path(PACKAGE, exe, env)
    assert path == prefix / "lib" / PACKAGE / exe
    # run from elsewhere so the repository checkout cannot be what gets imported
    p = subprocess.run([str(path), "--help"], capture_output=True, text=True, env=env, cwd=prefix, timeout=120)
    assert p.returncode == 0, f"exit {p.returncode}: {p.stderr}"
    assert "usage" in p.stdout.lower()
    console = prefix / "bin" / exe
    # pip wrote the installing interpreter into it (as "#!path", or through /bin/sh when the path is too long)
    assert sys.executable in "\n".join(console.read_text().splitlines()[:3])
    if exe == "sim_node":       # its help points at the installed interface pages
        docs = prefix / "share" / PACKAGE / "msg_docs"
        assert f"{docs}/" in p.stdout and (docs / "sim_node.md").is_file()


def test_a_missing_wrapper_target_is_one_line_and_exit_127(tmp_path):
    lib = tmp_path / "lib" / PACKAGE
    lib.mkdir(parents=True)
    (lib / "sim_node").write_bytes((ROOT / "scripts" / "sim_node").read_bytes())
    (lib / "sim_node").chmod(0o755)
    p = subprocess.run([str(lib / "sim_node"), "--help"], capture_output=True, text=True, timeout=30)
    assert p.returncode == 127 and p.stdout == ""
    assert p.stderr.count("\n") == 1 and "bin/sim_node is missing" in p.stderr


# ------------------------------------------------------------------------------------------- the launch file
def _calls(tree, name):
    return [n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", None) == name]


def _kw(call, name):
    return next((k.value for k in call.keywords if k.arg == name), None)


def test_launch_file_names_only_what_the_installed_package_has(prefix):
    from flagbot_sim.ros.beam_node import PARAMS as BEAM_PARAMS
    from flagbot_sim.ros.sim_node import PARAMS as SIM_PARAMS
    specs = {"sim_node": {s.name: s for s in SIM_PARAMS}, "beam_node": {s.name: s for s in BEAM_PARAMS},
             "cmd_profile": {}}
    path = prefix / "share" / PACKAGE / "launch" / "flagbot.launch.py"
    tree = ast.parse(path.read_text(), str(path))
    module_vars = {t.id: n.value for n in ast.walk(tree) if isinstance(n, ast.Assign) for t in n.targets
                   if isinstance(t, ast.Name)}
    declared = [row[0] for row in ast.literal_eval(module_vars["ARGUMENTS"])]
    assert {"scene", "n_flagella", "record"} <= set(declared)
    used = {ast.literal_eval(c.args[0]) for c in _calls(tree, "LaunchConfiguration")}
    assert used == set(declared), f"used but not declared: {used - set(declared)}, unused: {set(declared) - used}"

    nodes = _calls(tree, "Node")
    assert sorted(ast.literal_eval(_kw(n, "executable")) for n in nodes) == ["beam_node", "cmd_profile", "sim_node"]
    # the managed sim_node (lifecycle:=true): the same executable and parameters, its class chosen on the command line
    managed = _calls(tree, "LifecycleNode")
    assert [ast.literal_eval(_kw(n, "executable")) for n in managed] == ["sim_node"]
    assert ast.literal_eval(_kw(managed[0], "ros_arguments")) == ["-p", "lifecycle:=true"]
    nodes += managed
    py_types = {"str": "string", "int": "int", "float": "double", "bool": "bool"}
    for node in nodes:
        assert ast.literal_eval(_kw(node, "package")) == PACKAGE
        exe = ast.literal_eval(_kw(node, "executable"))
        exe_path = prefix / "lib" / PACKAGE / exe
        assert exe_path.is_file() and os.access(exe_path, os.X_OK), f"{exe}: not installed in lib/{PACKAGE}"
        params = _kw(node, "parameters")
        if isinstance(params, ast.Name):          # a list assigned in the same file
            params = module_vars[params.id]
        for d in (ast.walk(params) if params is not None else ()):
            if not isinstance(d, ast.Dict):
                continue
            items = []
            for k, v in zip(d.keys, d.values):
                if k is None:        # **name: a dict literal assigned in the same file
                    items += list(zip(module_vars[v.id].keys, module_vars[v.id].values))
                else:
                    items.append((k, v))
            for k, v in items:
                name = ast.literal_eval(k)
                assert name in specs[exe], f"{exe} declares no parameter {name!r}"
                assert getattr(v.func, "id", None) == "ParameterValue", f"{exe}.{name}: give it a value_type"
                value_type = _kw(v, "value_type").id
                assert py_types[value_type] == specs[exe][name].type_name, \
                    f"{exe}.{name} is a {specs[exe][name].type_name} parameter, the launch file passes {value_type}"


# ----------------------------------------------------------------------------------- optional parts, missing
@pytest.mark.parametrize("call, prog", [
    ("from flagbot_sim.console import sim_node; sys.exit(sim_node())", "sim_node"),
    ("from flagbot_sim.cli import main; sys.exit(main(['record', '-o', 'x.mcap']))", "flagbot record"),
    ("from flagbot_sim.cli import main; sys.exit(main(['replay', 'x.mcap']))", "flagbot replay"),
])
def test_a_ros_command_without_ros_says_so_in_one_line_naming_the_extra(call, prog, tmp_path):
    # None in sys.modules is Python's own way to make an import fail as if the module were not installed
    p = subprocess.run([sys.executable, "-c", f"import sys; sys.modules['rclpy'] = None; {call}"],
                       capture_output=True, text=True, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)),
                       cwd=tmp_path)
    assert p.returncode == optional.EXIT_CODE and p.stdout == ""       # the exit code of every missing extra
    assert p.stderr.count("\n") == 1, p.stderr
    assert p.stderr.startswith(f"error: {prog} needs ROS 2 Jazzy (rclpy), which {sys.executable} cannot import")
    assert p.stderr.rstrip().endswith("source /opt/ros/jazzy/setup.bash, or pip install 'flagbot_sim[ros]'")
    assert not (tmp_path / "x.mcap").exists()


def test_require_names_the_extra_only_when_the_extra_itself_is_missing(tmp_path, monkeypatch):
    with pytest.raises(optional.MissingExtra) as exc:
        optional.require("dask", "flagbot sweep --engine dask", module="flagbot_no_such_module")
    assert "\n" not in str(exc.value) and str(exc.value).endswith("pip install 'flagbot_sim[dask]'")
    assert isinstance(exc.value, ImportError)          # callers that catch ImportError still do
    # an installed module that fails on an import of its own is a real error, not a missing extra
    (tmp_path / "flagbot_broken_extra.py").write_text("import flagbot_no_such_dependency\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError) as exc:
        optional.require("dask", "a sweep", module="flagbot_broken_extra")
    assert not isinstance(exc.value, optional.MissingExtra) and exc.value.name == "flagbot_no_such_dependency"


def test_a_ros_install_that_cannot_load_says_so_in_one_line():
    """rclpy present but its C libraries not loadable (here: the wheels' start-up re-exec that sets their library
    path is skipped): the console script says so in one line and exits as for a missing extra (2), no 35-line
    traceback."""
    import os
    import subprocess
    import sys
    from pathlib import Path
    script = Path(sys.executable).with_name("sim_node")
    env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
    env["_ROS_WHEELS_BOOTSTRAP_COMPLETE"] = "1"
    p = subprocess.run([str(script), "--help"], env=env, capture_output=True, text=True, timeout=60)
    assert p.returncode == optional.EXIT_CODE, p.stdout + p.stderr
    assert "Traceback" not in p.stderr and p.stderr.count("\n") == 1
    assert p.stderr.startswith("error: sim_node: ROS 2 is installed but cannot be loaded: ")
