"""/tf and /tf_static where tf2_msgs may be missing: the message class when it is installed, and a recorder's
derivation of both topics from what it records when it is not.

On a ROS install ``tf2_msgs`` is importable: sim_node publishes /tf and /tf_static and a recorder records them as
any topic. The PyPI wheels this package runs on have no tf2_msgs, so nothing can publish them; a recording still
carries them: :class:`TfDeriver` turns the recorded ``odom`` / ``head_pose`` (world -> head), ``joint_states``
(the URDF's moving joints) and ``robot_description`` (its fixed joints, on /tf_static) into the same transforms,
written with the CDR encoder of :mod:`flagbot_sim.bag.tf`. The transforms are those of
:mod:`flagbot_sim.tf_tree`, the ones sim_node publishes itself where it can.
"""
from __future__ import annotations

import collections
import functools
import importlib
import threading

from ..bag import QosInfo, qos_to_yaml
from ..bag.tf import TF_MESSAGE, Transform, encode_tf_message
from ..tf_tree import TfTree, UrdfError, pose_transform, stamp_ns_of
from .. import topics as names

#: /tf: what tf2's TransformBroadcaster offers (reliable, volatile, keep last 100)
TF_QOS = QosInfo(depth=100)
#: /tf_static: tf2's StaticTransformBroadcaster (reliable, transient local, keep last 1): a late subscriber gets it
TF_STATIC_QOS = QosInfo(depth=1, durability="transient_local")
_RECENT = 64        # world -> head stamps remembered, to send each once
NO_TF2 = ("tf2_msgs is not installed (no wheel on PyPI; on a ROS install: apt install ros-jazzy-tf2-msgs)")


@functools.lru_cache(maxsize=None)
def tf_message_class():
    """``tf2_msgs.msg.TFMessage``, or None where tf2_msgs is not importable."""
    try:
        return importlib.import_module("tf2_msgs.msg").TFMessage
    except (ImportError, AttributeError):
        return None


def ros_tf_message(transforms: list[Transform]):
    """A ``tf2_msgs/msg/TFMessage`` (the installed class) holding ``transforms``."""
    from geometry_msgs.msg import TransformStamped
    msg = tf_message_class()()
    for t in transforms:
        m = TransformStamped()
        m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(t.stamp_ns), 1_000_000_000)
        m.header.frame_id = t.parent
        m.child_frame_id = t.child
        m.transform.translation.x, m.transform.translation.y, m.transform.translation.z = t.translation
        (m.transform.rotation.x, m.transform.rotation.y, m.transform.rotation.z,
         m.transform.rotation.w) = t.rotation
        msg.transforms.append(m)
    return msg


def head_transform(stamp_ns: int, frame: str, child: str, pose) -> Transform:
    """world -> head from a ``geometry_msgs/Pose`` (head_pose's, odometry's)."""
    p, q = pose.position, pose.orientation
    return pose_transform(stamp_ns, frame, child, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


class TfDeriver:
    """Derive /tf and /tf_static messages from the recorded messages of a robot's topics.

    :param resolve: turns a relative topic name into the recorded one (the recording node's resolve_topic_name),
        so a namespaced robot's ``/bot1/odom`` is read.
    :param tf, tf_static: which of the two to derive.

    :meth:`derive` takes each recorded message (topic, CDR bytes) and returns ``(topic, CDR bytes, stamp_ns)``
    for the TF messages it implies: ``odom`` or ``head_pose`` -> /tf world -> head (the header's frame to the
    odometry's child frame, or the URDF's root link, once either is known; a stamp is sent once), ``joint_states`` -> /tf of the moving joints, ``robot_description`` -> /tf_static of the fixed joints
    (again whenever the description changes). Stamps are the messages' header stamps (simulation time); a
    /tf_static message takes the last stamp seen.
    """

    def __init__(self, resolve=lambda t: t, *, tf: bool = True, tf_static: bool = True):
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import JointState
        from std_msgs.msg import String
        self.tf, self.tf_static = tf, tf_static
        self._sources = {resolve(names.HEAD_POSE): (PoseStamped, self._pose),
                         resolve(names.ODOM): (Odometry, self._odom),
                         resolve(names.JOINT_STATES): (JointState, self._joints),
                         resolve(names.ROBOT_DESCRIPTION): (String, self._description)}
        self.tree: TfTree | None = None
        self._description_text = None
        self._child: str | None = None            # odometry's child frame
        # (stamp, parent, child) of the world -> head transforms sent lately: odometry and head pose of one step
        # carry the same pose, and either may come first (or a step late: two topics, two queues)
        self._sent_head: set[tuple] = set()
        self._sent_order: collections.deque = collections.deque()
        self._stamp = 0
        self.error = ""                            # why the last robot_description could not be read
        self._lock = threading.Lock()
        self._added: set[str] = set()

    @property
    def topics(self) -> list[str]:
        """The topics this deriver writes."""
        return [t for t, on in ((names.TF, self.tf), (names.TF_STATIC, self.tf_static)) if on]

    def record(self, writer, topic: str, data: bytes, log_time_ns: int) -> None:
        """Write what :meth:`derive` gives for one recorded message into ``writer`` (a BagWriter), with the
        source's log time; each TF topic is registered with tf2's QoS when its first message comes."""
        with self._lock:
            for tf_topic, tf_data, stamp in self.derive(topic, data, log_time_ns):
                if tf_topic not in self._added:
                    add_derived_topic(writer, tf_topic)
                    self._added.add(tf_topic)
                writer.write(tf_topic, tf_data, log_time_ns, publish_time_ns=stamp or log_time_ns)

    @property
    def sources(self) -> list[str]:
        return list(self._sources)

    def derive(self, topic: str, data: bytes, stamp_ns: int) -> list[tuple[str, bytes, int]]:
        """The TF messages ``data`` (received on ``topic`` at ``stamp_ns``) implies; [] for other topics and for
        bytes that do not decode."""
        src = self._sources.get(topic)
        if src is None:
            return []
        from rclpy.serialization import deserialize_message
        try:
            msg = deserialize_message(bytes(data), src[0])
        except Exception:  # noqa: BLE001 - a message that does not decode implies nothing
            return []
        return [(t, encode_tf_message(tr), tr[0].stamp_ns) for t, tr in src[1](msg, stamp_ns) if tr]

    def _head(self, stamp: int, frame: str, pose):
        child = self._child or (self.tree.root if self.tree is not None else None)
        self._stamp = max(self._stamp, stamp)
        key = (stamp, frame, child)
        if not self.tf or child is None or not frame or key in self._sent_head:
            return []
        self._sent_head.add(key)
        self._sent_order.append(key)
        if len(self._sent_order) > _RECENT:
            self._sent_head.discard(self._sent_order.popleft())
        return [(names.TF, [head_transform(stamp, frame, child, pose)])]

    def _pose(self, msg, _):
        return self._head(stamp_ns_of(msg.header.stamp), msg.header.frame_id, msg.pose)

    def _odom(self, msg, _):
        self._child = msg.child_frame_id or None
        return self._head(stamp_ns_of(msg.header.stamp), msg.header.frame_id, msg.pose.pose)

    def _joints(self, msg, _):
        stamp = stamp_ns_of(msg.header.stamp)
        self._stamp = max(self._stamp, stamp)
        if not self.tf or self.tree is None:
            return []
        return [(names.TF, self.tree.joint_transforms(stamp, msg.name, msg.position))]

    def _description(self, msg, _):
        if msg.data == self._description_text:
            return []
        self._description_text = msg.data
        try:
            self.tree = TfTree(msg.data)
            self.error = ""
        except UrdfError as exc:
            self.tree, self.error = None, f"robot_description is not a URDF this recorder reads: {exc}"
            return []
        return [(names.TF_STATIC, self.tree.static_transforms(self._stamp))] if self.tf_static else []


def add_derived_topic(writer, topic: str) -> None:
    """Register /tf or /tf_static in a bag writer with tf2's QoS (what a broadcaster would have offered)."""
    qos = TF_STATIC_QOS if topic == names.TF_STATIC else TF_QOS
    writer.add_topic(topic, TF_MESSAGE, offered_qos_profiles=qos_to_yaml([qos]))


def recorder_deriver(node, selected) -> TfDeriver | None:
    """The deriver a recorder on ``node`` uses: None where tf2_msgs is installed (/tf and /tf_static are then
    recorded as published) or when ``selected`` (the recorder's topic filter) takes neither; else one that
    derives the selected ones, said once in the log."""
    tf, tf_static = selected(names.TF), selected(names.TF_STATIC)
    if tf_message_class() is not None or not (tf or tf_static):
        return None
    d = TfDeriver(node.resolve_topic_name, tf=tf, tf_static=tf_static)
    node.get_logger().info(f"{NO_TF2}: deriving {' and '.join(d.topics)} from {', '.join(d.sources)}")
    return d
