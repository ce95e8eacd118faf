"""The URDF of head and plate (flagbot_sim/urdf.py, no ROS): the committed urdf/*.urdf are the generator's output,
each is a valid tree rooted at the head body frame, its joints are joint_states' and its sizes the scene's."""
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from flagbot_sim.scene import load_scene
from flagbot_sim.urdf import JOINT_NAMES, base_joint, base_link, main, robot_urdf

URDF_DIR = Path(__file__).resolve().parents[1] / "urdf"


@pytest.mark.parametrize("scene", ["design1", "design2"])
def test_committed_file_is_the_generators_output(scene):
    committed = (URDF_DIR / f"{scene}.urdf").read_text()
    assert committed == robot_urdf(load_scene(scene)), (
        f"urdf/{scene}.urdf is stale: python -m flagbot_sim.urdf {scene} > urdf/{scene}.urdf")


def tree(text):
    root = ET.fromstring(text)
    links = [l.get("name") for l in root.iter("link")]
    joints = {j.get("name"): (j.find("parent").get("link"), j.find("child").get("link"), j) for j in
              root.iter("joint")}
    return root, links, joints


@pytest.mark.parametrize("scene", ["design1", "design2"])
def test_tree_joints_and_geometry(scene):
    sc = load_scene(scene)
    root, links, joints = tree((URDF_DIR / f"{scene}.urdf").read_text())
    assert len(set(links)) == len(links)
    moving = {n: v for n, v in joints.items() if v[2].get("type") != "fixed"}
    assert tuple(moving) == JOINT_NAMES
    # the fixed frames: one per flagellum base, on the plate
    n = sc.robot.n_flagella
    assert {n: (p, c) for n, (p, c, _) in joints.items() if n not in moving} == {
        base_joint(i): ("plate", base_link(i)) for i in range(n)}
    children = [c for _, c, _ in joints.values()]
    assert sorted(children) == sorted(set(children))                 # every link has at most one parent
    roots = set(links) - set(children)
    assert roots == {"head"}                                          # one tree, rooted at the head body frame
    assert all(p in links and c in links for p, c, _ in joints.values())
    for _, _, j in moving.values():                                  # spins about the robot axis
        assert j.get("type") == "continuous" and j.find("axis").get("xyz") == "-1 0 0"
    head = root.find("link[@name='head']/visual/geometry/sphere")
    assert float(head.get("radius")) == pytest.approx(sc.head.radius)
    disc = root.find("link[@name='plate']/visual")
    cyl = disc.find("geometry/cylinder")
    assert float(cyl.get("radius")) == pytest.approx(sc.plate.diameter / 2)
    assert float(cyl.get("length")) == pytest.approx(sc.plate.thickness)
    x = float(disc.find("origin").get("xyz").split()[0])
    # behind the head: from the joint (one head radius back) over the socket length
    assert x == pytest.approx(-sc.head.radius - sc.plate.thickness / 2)
    assert float(disc.find("origin").get("rpy").split()[1]) == pytest.approx(math.pi / 2, abs=1e-8)


def test_clamped_scene_has_no_head_and_root_link_follows_the_frame_name():
    root, links, joints = tree(robot_urdf(load_scene("clamped_flagellum"), head_link="bot1/head"))
    assert root.find("link[@name='bot1/head']") is not None and root.find("link[@name='bot1/head']/visual") is None
    assert joints["motor"][0] == "bot1/head"


def test_command_line_prints_the_urdf_with_overrides(capsys):
    assert main(["design1", "--set", "head.radius=0.03"]) == 0
    root, _, _ = tree(capsys.readouterr().out)
    assert float(root.find("link[@name='head']/visual/geometry/sphere").get("radius")) == 0.03
    assert main(["design1", "--set", "head.radius=-1"]) == 2
    assert "head.radius" in capsys.readouterr().err


@pytest.mark.parametrize("n", [1, 3, 4])
def test_flagellum_base_frames_are_where_the_simulation_starts_each_flagellum(n):
    """At rest the head frame is the fixed frame (convert.py), so the tree's head -> plate -> flagellum_<i> at
    zero joint angles lands on the first node of flagellum i's centreline, as the simulation builds it."""
    from flagbot_sim import world
    from flagbot_sim.physics import Simulation
    from flagbot_sim.tf_tree import TfTree, rotate
    sc = load_scene("design1", [f"robot.n_flagella={n}"])
    sim = Simulation(sc)
    o = sim.observer.position(sim.initial)
    bases = [world.to_world(c, o)[0] for c in sim.flagella_centrelines()]
    t = TfTree(robot_urdf(sc))
    plate = t.joint_transforms(0, ["motor"], [0.0])[0]
    statics = {s.child: s for s in t.static_transforms(0)}
    assert len(statics) == n
    for i, base in enumerate(bases):
        s = statics[base_link(i)]
        assert s.parent == plate.child == "plate"
        p = [a + b for a, b in zip(plate.translation, rotate(plate.rotation, s.translation))]
        assert p == pytest.approx(list(base), abs=1e-9)      # the URDF writes 9 digits
