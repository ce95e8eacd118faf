"""flagbot_sim: an ament_python ROS 2 package that is also pip-installable.

Executables are reachable two ways (see ../shared/ROS_NOTES.md): console scripts on PATH for pip users, and
small wrapper executables installed through data_files into lib/flagbot_sim/ for `ros2 run flagbot_sim ...`.
There is deliberately no setup.cfg moving install_scripts, because that would take the console scripts off PATH.
"""
import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = "flagbot_sim"

# name -> module:function; each also has a wrapper in scripts/ installed to lib/flagbot_sim/
EXECUTABLES = {
    "flagbot": "flagbot_sim.cli:main",
    "sim_node": "flagbot_sim.ros.sim_node:main",
    "beam_node": "flagbot_sim.ros.beam_node:main",
    "cmd_profile": "flagbot_sim.ros.cmd_profile:main",
    "record": "flagbot_sim.ros.recorder:main",
    "replay": "flagbot_sim.ros.replay:main",
}

setup(
    name=package_name,
    version=re.search(r'__version__ = "(.+)"', Path("flagbot_sim/__init__.py").read_text()).group(1),
    packages=find_packages(include=["flagbot_sim", "flagbot_sim.*"]),
    package_data={"flagbot_sim": ["scenes/*.toml", "ros/*.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/scenes", sorted(glob("flagbot_sim/scenes/*.toml"))),
        ("lib/" + package_name, ["scripts/" + name for name in EXECUTABLES]),
    ],
    python_requires=">=3.10",
    install_requires=["numpy", "scipy"],
    zip_safe=False,
    maintainer="flagbot_sim developers",
    maintainer_email="dev@flagbot.local",
    description="Virtual soft flagellated robot in granular media: DER simulator, beam estimator, ROS 2 nodes",
    license="MIT",
    tests_require=["pytest"],
    entry_points={"console_scripts": [f"{name} = {target}" for name, target in EXECUTABLES.items()]},
)
