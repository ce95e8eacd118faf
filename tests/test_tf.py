"""/tf without the tf2_msgs wheel: the TFMessage CDR encoder (flagbot_sim/bag/tf.py) against rosbags' Jazzy
typestore, its schema, the URDF tree reader (flagbot_sim/tf_tree.py) and the recorder's derivation
(flagbot_sim/ros/tf_derive.py). No DDS here; the recordings of a live sim_node are in test_ros_sim_node.py."""
import math

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from flagbot_sim.bag.schema import message_definition
from flagbot_sim.bag.tf import TF_MESSAGE, Transform, decode_tf_message, encode_tf_message
from flagbot_sim.tf_tree import TfTree, UrdfError, quat_from_rpy, rotate

JAZZY = get_typestore(Stores.ROS2_JAZZY)

TRANSFORMS = [
    Transform(12_345_678_901, "world", "head", (0.125, -3.5e-3, 1e-9), (0.0, 0.0, math.sin(0.3), math.cos(0.3))),
    Transform(0, "head", "plate", (0.0, 0.0, 0.0), (-math.sin(1.1), 0.0, 0.0, math.cos(1.1))),
    # frame names of every length mod 4 (string padding) and a non-ASCII one
    Transform(999_999_999, "a", "bc", (1.0, 2.0, 3.0), (0.5, 0.5, 0.5, 0.5)),
    Transform(1, "abc", "bot1/flagellum_0", (-1.0, 0.0, 2.0), (0.0, 1.0, 0.0, 0.0)),
    Transform(2_000_000_000, "wörld", "x", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)),
]


def rosbags_message(transforms):
    T = JAZZY.types
    Time = T["builtin_interfaces/msg/Time"]
    return T[TF_MESSAGE](transforms=[T["geometry_msgs/msg/TransformStamped"](
        header=T["std_msgs/msg/Header"](stamp=Time(sec=t.stamp_ns // 10 ** 9, nanosec=t.stamp_ns % 10 ** 9),
                                        frame_id=t.parent),
        child_frame_id=t.child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=t.translation[0], y=t.translation[1], z=t.translation[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=t.rotation[0], y=t.rotation[1], z=t.rotation[2],
                                                      w=t.rotation[3])))
        for t in transforms])


@pytest.mark.parametrize("count", [0, 1, 2, len(TRANSFORMS)])
def test_encoder_writes_the_bytes_rosbags_writes_and_rosbags_reads_them(count):
    items = TRANSFORMS[:count]
    data = encode_tf_message(items)
    assert data == bytes(JAZZY.serialize_cdr(rosbags_message(items), TF_MESSAGE))
    msg = JAZZY.deserialize_cdr(data, TF_MESSAGE)
    assert [(t.header.stamp.sec * 10 ** 9 + t.header.stamp.nanosec, t.header.frame_id, t.child_frame_id,
             (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z),
             (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z, t.transform.rotation.w))
            for t in msg.transforms] == [(t.stamp_ns, t.parent, t.child, t.translation, t.rotation) for t in items]
    assert decode_tf_message(data) == items


def test_decoder_reads_big_endian_and_refuses_truncated_bytes():
    data = bytes(JAZZY.serialize_cdr(rosbags_message(TRANSFORMS), TF_MESSAGE, little_endian=False))
    assert data[:2] == b"\x00\x00"
    assert decode_tf_message(data) == TRANSFORMS
    good = encode_tf_message(TRANSFORMS)
    for cut in (3, 8, 20, len(good) - 1):
        with pytest.raises(ValueError):
            decode_tf_message(good[:cut])
    with pytest.raises(ValueError):
        encode_tf_message([Transform(0, "a\x00b", "c")])


def test_schema_is_the_full_definition_and_parses_to_the_jazzy_type():
    text = message_definition(TF_MESSAGE)
    assert text.startswith("geometry_msgs/TransformStamped[] transforms\n")
    for dep in ("geometry_msgs/TransformStamped", "geometry_msgs/Transform", "geometry_msgs/Vector3",
                "geometry_msgs/Quaternion", "std_msgs/Header", "builtin_interfaces/Time"):
        assert text.count(f"\nMSG: {dep}\n") == 1, dep
    # the text alone (as a reader of the bag sees it) gives the type rosbags ships for Jazzy: same fields
    store = get_typestore(Stores.EMPTY)
    types = {}
    for i, part in enumerate(text.split("=" * 80 + "\n")):
        if i == 0:
            name, body = TF_MESSAGE, part
        else:
            head, body = part.split("\n", 1)
            name = head.removeprefix("MSG: ").replace("/", "/msg/", 1)
        types.update(get_types_from_msg(body, name))
    store.register(types)
    assert store.fielddefs[TF_MESSAGE] == JAZZY.fielddefs[TF_MESSAGE]
    data = encode_tf_message(TRANSFORMS)
    assert bytes(store.serialize_cdr(store.deserialize_cdr(data, TF_MESSAGE), TF_MESSAGE)) == data


# ---------------------------------------------------------------------------------------------------- tree
URDF = """<?xml version="1.0"?>
<robot name="t">
  <link name="base"/><link name="arm"/><link name="slider"/><link name="tool"/><link name="cam"/>
  <joint name="j_arm" type="revolute">
    <parent link="base"/><child link="arm"/>
    <origin xyz="0 0 1" rpy="0 0 1.5707963267948966"/><axis xyz="0 0 2"/>
  </joint>
  <joint name="j_slide" type="prismatic">
    <parent link="arm"/><child link="slider"/><origin xyz="1 0 0" rpy="0 0 1.5707963267948966"/>
  </joint>
  <joint name="j_tool" type="fixed">
    <parent link="slider"/><child link="tool"/><origin xyz="0 0.5 0" rpy="0.1 0.2 0.3"/>
  </joint>
  <joint name="j_cam" type="floating"><parent link="base"/><child link="cam"/></joint>
</robot>"""


def matrix(q):
    return np.array([rotate(q, e) for e in np.eye(3)]).T


def rpy_matrix(r, p, y):
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def test_tree_gives_fixed_joints_once_and_moving_joints_from_positions():
    t = TfTree(URDF)
    assert t.root == "base" and t.moving_joints == ["j_arm", "j_slide"]
    (tool,) = t.static_transforms(7)
    assert (tool.stamp_ns, tool.parent, tool.child, tool.translation) == (7, "slider", "tool", (0.0, 0.5, 0.0))
    assert matrix(tool.rotation) == pytest.approx(rpy_matrix(0.1, 0.2, 0.3), abs=1e-12)
    assert matrix(quat_from_rpy(0.1, 0.2, 0.3)) == pytest.approx(rpy_matrix(0.1, 0.2, 0.3), abs=1e-12)
    arm, slide = t.joint_transforms(5, ["j_cam", "unknown", "j_arm", "j_slide"], [9.0, 9.0, 0.5, 0.25])
    assert (arm.parent, arm.child, arm.translation, arm.stamp_ns) == ("base", "arm", (0.0, 0.0, 1.0), 5)
    # origin rotation (yaw pi/2) then the joint's 0.5 rad about its (normalised) z axis
    assert matrix(arm.rotation) == pytest.approx(rpy_matrix(0, 0, math.pi / 2 + 0.5), abs=1e-12)
    # prismatic along the default axis x, turned by the origin's yaw: 0.25 m along the parent's y
    assert slide.translation == pytest.approx((1.0, 0.25, 0.0), abs=1e-12)
    assert matrix(slide.rotation) == pytest.approx(rpy_matrix(0, 0, math.pi / 2), abs=1e-12)


@pytest.mark.parametrize("text", ["<robot", "<notrobot/>",
                                  '<robot><joint name="j" type="screw"><parent link="a"/><child link="b"/></joint>'
                                  "</robot>",
                                  '<robot><joint name="j" type="fixed"><parent link="a"/><child link="b"/>'
                                  '<origin xyz="1 2"/></joint></robot>',
                                  '<robot><joint name="j" type="revolute"><parent link="a"/><child link="b"/>'
                                  '<axis xyz="0 0 0"/></joint></robot>'])
def test_tree_refuses_what_it_cannot_read(text):
    with pytest.raises(UrdfError):
        TfTree(text)


# ---------------------------------------------------------------------------------------------------- derivation
def test_deriver_turns_a_namespaced_robots_topics_into_tf_once_per_stamp():
    """What the recorder writes where tf2_msgs is missing: /bot1/odom and /bot1/head_pose of one step give one
    world -> head, joint_states the moving joints once the URDF is known, robot_description the fixed joints
    (stamped with the last stamp seen) and again only when it changes; an unreadable URDF is reported."""
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from flagbot_sim.ros.tf_derive import TfDeriver
    from flagbot_sim.scene import load_scene
    from flagbot_sim.urdf import robot_urdf

    d = TfDeriver(lambda t: t if t.startswith("/") else "/bot1/" + t)
    assert sorted(d.sources) == ["/bot1/head_pose", "/bot1/joint_states", "/bot1/odom", "/bot1/robot_description"]

    def run(topic, msg):
        return [(t, decode_tf_message(data), stamp) for t, data, stamp in d.derive(topic, serialize_message(msg), 5)]

    pose = PoseStamped()
    pose.header.stamp.sec, pose.header.stamp.nanosec, pose.header.frame_id = 2, 500, "map"
    pose.pose.position.x, pose.pose.orientation.z, pose.pose.orientation.w = 0.25, 0.6, 0.8
    assert run("/bot1/head_pose", pose) == []           # no child frame known yet (no odometry, no URDF)
    assert run("/head_pose", pose) == []                 # another robot's topic
    odom = Odometry()
    odom.header, odom.child_frame_id, odom.pose.pose = pose.header, "bot1/head", pose.pose
    expected = [("/tf", [Transform(2_000_000_500, "map", "bot1/head", (0.25, 0.0, 0.0), (0.0, 0.0, 0.6, 0.8))],
                 2_000_000_500)]
    assert run("/bot1/odom", odom) == expected
    assert run("/bot1/head_pose", pose) == []           # the same step: not sent twice
    joints = JointState(name=["head_spin", "flagella_spin", "motor"], position=[0.1, 0.2, 0.3])
    joints.header.stamp.sec = 3
    assert run("/bot1/joint_states", joints) == []      # no URDF yet
    assert d.derive("/bot1/robot_description", b"\x00\x01\x00\x00garbage", 5) == []
    urdf = robot_urdf(load_scene("design1", ["robot.n_flagella=2"]), "bot1/head")
    ((topic, statics, stamp),) = run("/bot1/robot_description", String(data=urdf))
    assert topic == "/tf_static" and stamp == 3_000_000_000
    assert [(s.parent, s.child) for s in statics] == [("plate", "flagellum_0"), ("plate", "flagellum_1")]
    assert run("/bot1/robot_description", String(data=urdf)) == []     # unchanged: nothing new
    ((topic, moving, _),) = run("/bot1/joint_states", joints)
    assert topic == "/tf" and [(t.parent, t.child) for t in moving] == [
        ("bot1/head", "head_axis"), ("head_axis", "flagella"), ("bot1/head", "plate")]
    assert moving[2].rotation == pytest.approx((-math.sin(0.15), 0.0, 0.0, math.cos(0.15)))
    assert run("/bot1/robot_description", String(data="<robot><joint/></robot>")) == [] and d.tree is None
    assert "robot_description" in d.error
    only_tf = TfDeriver(tf_static=False)
    assert only_tf.topics == ["/tf"] and only_tf.derive("/robot_description", serialize_message(String(data=urdf)),
                                                        0) == []


def test_ros_message_holds_the_transforms(monkeypatch):
    """What sim_node publishes where tf2_msgs is installed: the installed class (here a stand-in, no wheel exists)
    filled with geometry_msgs/TransformStamped, field for field the transforms the recorder would encode."""
    from flagbot_sim.ros import tf_derive

    class TFMessage:
        def __init__(self):
            self.transforms = []
    monkeypatch.setattr(tf_derive, "tf_message_class", lambda: TFMessage)
    msg = tf_derive.ros_tf_message(TRANSFORMS)
    assert isinstance(msg, TFMessage)
    assert [Transform(t.header.stamp.sec * 10 ** 9 + t.header.stamp.nanosec, t.header.frame_id, t.child_frame_id,
                      (t.transform.translation.x, t.transform.translation.y, t.transform.translation.z),
                      (t.transform.rotation.x, t.transform.rotation.y, t.transform.rotation.z,
                       t.transform.rotation.w)) for t in msg.transforms] == TRANSFORMS
