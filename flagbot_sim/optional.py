"""Optional extras: which module each pip extra brings, and the one-line message when it is missing.

``pip install flagbot_sim`` installs what the simulator, the beam estimator, recordings and plots need
(setup.py ``install_requires``). The rest is an extra, named in setup.py ``extras_require`` with the same keys as
:data:`EXTRAS` (a test keeps the two in step):

- ``ros``: the ROS 2 Jazzy wheels from PyPI. Not a plain requirement, because on a ROS install (apt / colcon,
  ``source /opt/ros/jazzy/setup.bash``) rclpy comes from the ROS prefix, and pip must not pull a second rclpy
  over it.
- ``dask``: sweeps on a Dask distributed cluster; ``bench``: the PyElastica comparison; ``view``: Foxglove.

A command that needs a missing extra does nothing and exits with :data:`EXIT_CODE` (2, the code of every
refusal made before any work: bad arguments, a bad scene, an output path that cannot be written), after one line
``error: <purpose> needs <what>, which <python> cannot import: pip install 'flagbot_sim[<extra>]'``; every
command and console script, for every extra (docs/cli.md).

Leaf module: imports nothing from the package, and the extras only when asked.
"""
from __future__ import annotations

import importlib
import sys
from types import ModuleType

#: extra -> (module that proves it is installed, what it is, how else to get it)
EXTRAS = {
    "ros": ("rclpy", "ROS 2 Jazzy (rclpy)", "source /opt/ros/jazzy/setup.bash, or "),
    "dask": ("distributed", "Dask distributed", ""),
    "bench": ("elastica", "PyElastica", ""),
    "view": ("foxglove", "the Foxglove SDK", ""),
}

#: top-level modules that come with the ROS 2 install (or the ``ros`` extra's wheels)
ROS_MODULES = frozenset({"rclpy", "rcl_interfaces", "builtin_interfaces", "ament_index_python", "std_msgs",
                         "geometry_msgs", "sensor_msgs", "nav_msgs", "visualization_msgs", "rosgraph_msgs",
                         "diagnostic_msgs", "std_srvs"})


#: exit code of a command that needs an extra which is not installed (the same for every extra and command)
EXIT_CODE = 2


class MissingExtra(ImportError):
    """An optional part is not installed; ``str()`` is the one-line message naming the extra."""

    def __init__(self, extra: str, purpose: str):
        module, what, other = EXTRAS[extra]
        super().__init__(f"{purpose} needs {what}, which {sys.executable} cannot import: "
                         f"{other}pip install 'flagbot_sim[{extra}]'", name=module)
        self.extra = extra


def require(extra: str, purpose: str, module: str | None = None) -> ModuleType:
    """Import ``module`` (default: the extra's marker module) or raise :class:`MissingExtra` for ``purpose``."""
    module = module or EXTRAS[extra][0]
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        # only the extra itself being absent is "missing"; an error inside an installed extra stays as it is
        if exc.name is None or exc.name.split(".")[0] != module.split(".")[0]:
            raise
        raise MissingExtra(extra, purpose) from None


def report_missing(exc: MissingExtra) -> int:
    """Print ``exc`` as the one ``error:`` line on stderr; the exit code to end with (:data:`EXIT_CODE`)."""
    print(f"error: {exc}", file=sys.stderr)
    return EXIT_CODE


def available(extra: str) -> bool:
    """Whether the extra's marker module can be found (without importing it)."""
    import importlib.util
    return importlib.util.find_spec(EXTRAS[extra][0]) is not None


def missing_ros(exc: ImportError, purpose: str) -> MissingExtra | None:
    """The ``ros`` extra's MissingExtra when ``exc`` is ROS 2 itself being absent (rclpy, a message package),
    else None: the caller re-raises anything else."""
    if isinstance(exc, ModuleNotFoundError) and (exc.name or "").split(".")[0] in ROS_MODULES:
        return MissingExtra("ros", purpose)
    return None
