"""flagbot_sim: an ament_python ROS 2 package that is also pip-installable.

Executables are reachable two ways (see ../shared/ROS_NOTES.md): console scripts on PATH for pip users, and
small wrapper executables installed through data_files into lib/flagbot_sim/ for `ros2 run flagbot_sim ...`.
There is deliberately no setup.cfg moving install_scripts, because that would take the console scripts off PATH.
Each wrapper execs ../../bin/<name>, the console script, so both ways run the Python the package was installed with.

Dependencies (README "Dependencies, and why"): install_requires is everything a run, a sweep, a recording and its
plots import. ROS 2 is the extra [ros], not a requirement: on a ROS install rclpy comes from /opt/ros (rosdep +
package.xml), and pip must not pull the PyPI wheels over it. flagbot_sim/optional.py names each extra's module
and prints the one-line message when one is missing.
"""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "flagbot_sim"

# name -> module:function; each also has a wrapper in scripts/ installed to lib/flagbot_sim/. The ROS processes
# start through console.py, which turns a missing rclpy into one line naming the [ros] extra.
EXECUTABLES = {
    "flagbot": "flagbot_sim.cli:main",
    "sim_node": "flagbot_sim.console:sim_node",
    "beam_node": "flagbot_sim.console:beam_node",
    "cmd_profile": "flagbot_sim.console:cmd_profile",
    "record": "flagbot_sim.console:record",
    "replay": "flagbot_sim.console:replay",
}

INSTALL_REQUIRES = [
    "numpy>=1.24",
    "scipy>=1.10",              # sparse LU, solve_bvp (beam estimator, reference rod), optimisation
    "numba>=0.60",              # the compiled kernels of the hot path: required (NUMBA_DISABLE_JIT=1 to debug)
    "llvmlite",                 # numba's own; imported directly to bind scipy's LAPACK for the compiled solver
    "mcap>=1.1",                # recordings in rosbag2's MCAP layout
    "mcap-ros2-support>=0.5",   # decoding recorded ROS 2 messages (bag-summary, replay)
    "zstandard",                # compressed MCAP chunks (mcap's own dependencies, imported directly by bag.py)
    "lz4",
    "matplotlib>=3.7",          # sweep figures, bag-summary plots, the accuracy study
]

EXTRAS_REQUIRE = {
    # ROS 2 Jazzy from PyPI wheels, for a machine without a ROS install (x86_64, CPython 3.10-3.13)
    "ros": ["ros-jazzy-rclpy>=7.1", "ros-jazzy-common-interfaces", "ros-jazzy-rmw-fastrtps-cpp"],
    "dask": ["dask[distributed]>=2024.8"],     # flagbot sweep --engine dask
    "bench": ["pyelastica>=1.0"],              # the PyElastica comparison in flagbot bench speed
    "view": ["foxglove-sdk"],                  # the Foxglove live view
}

setup(
    name=package_name,
    version=re.search(r'__version__ = "(.+)"', Path("flagbot_sim/__init__.py").read_text()).group(1),
    packages=find_packages(include=["flagbot_sim", "flagbot_sim.*"]),
    package_data={"flagbot_sim": ["scenes/*.toml", "ros/*.xml", "view/*.foxglove-layout.json"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/scenes", sorted(glob("flagbot_sim/scenes/*.toml"))),
        ("share/" + package_name + "/msg_docs", sorted(glob("msg_docs/*.md"))),
        ("share/" + package_name + "/launch", sorted(glob("launch/*.py"))),
        ("share/" + package_name + "/urdf", sorted(glob("urdf/*.urdf"))),
        ("share/" + package_name + "/foxglove", sorted(glob("flagbot_sim/view/*.foxglove-layout.json"))),
        ("lib/" + package_name, ["scripts/" + name for name in EXECUTABLES]),
    ],
    python_requires=">=3.11",           # tomllib
    install_requires=INSTALL_REQUIRES,
    extras_require=EXTRAS_REQUIRE,
    zip_safe=False,
    maintainer="flagbot_sim developers",
    maintainer_email="dev@flagbot.local",
    description="Virtual soft flagellated robot in granular media: DER simulator, beam estimator, ROS 2 nodes",
    license="MIT",
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
