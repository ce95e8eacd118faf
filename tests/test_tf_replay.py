"""The replayer and /tf: every recording carries /tf and /tf_static (tf2_msgs/msg/TFMessage); the replayer
republishes them where tf2_msgs is installed (here: a stand-in tf2_msgs module, since no wheel exists) and, where
it is not, says once that it skips them and replays the rest."""
import sys
import types

import pytest
from rclpy.qos import DurabilityPolicy
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64

from flagbot_sim.bag import BagWriter, QosInfo, qos_to_yaml
from flagbot_sim.bag.tf import Transform, encode_tf_message
from flagbot_sim.ros import tf_derive
from flagbot_sim.ros.replay import Replayer


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / "tf.mcap"
    sent = {"/tf": [], "/tf_static": [], "/speed": []}
    with BagWriter(path) as w:
        tf_derive.add_derived_topic(w, "/tf")
        tf_derive.add_derived_topic(w, "/tf_static")
        w.add_topic("/speed", "std_msgs/msg/Float64", offered_qos_profiles=qos_to_yaml([QosInfo()]))
        sent["/tf_static"].append(encode_tf_message([Transform(0, "plate", "flagellum_0", (1.0, 2.0, 3.0))]))
        w.write("/tf_static", sent["/tf_static"][-1], 10 ** 9)
        for k in range(5):
            t = 10 ** 9 + k * 10 ** 7
            sent["/tf"].append(encode_tf_message([Transform(t, "world", "head", (0.1 * k, 0.0, 0.0))]))
            sent["/speed"].append(serialize_message(Float64(data=float(k))))
            w.write("/tf", sent["/tf"][-1], t)
            w.write("/speed", sent["/speed"][-1], t)
    return path, sent


class Log:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(text)

    info = warn = error = warning


class LoggedNode:
    """A real node whose log the test reads."""

    def __init__(self, node):
        self._node, self.log = node, Log()

    def get_logger(self):
        return self.log

    def __getattr__(self, name):
        return getattr(self._node, name)


class Pub:
    def __init__(self, cls, qos):
        self.cls, self.qos, self.sent = cls, qos, []

    def publish(self, data):
        self.sent.append(bytes(data))


class FakeNode:
    """Publishers that keep what they are given (a stand-in TFMessage has no type support to publish with)."""

    def __init__(self, context):
        self.context, self.log, self.pubs = context, Log(), {}

    def get_logger(self):
        return self.log

    def create_publisher(self, cls, topic, qos):
        self.pubs[topic] = Pub(cls, qos)
        return self.pubs[topic]


def test_without_tf2_msgs_the_replay_says_once_that_it_skips_tf_and_replays_the_rest(ros, bag):
    path, sent = bag
    assert tf_derive.tf_message_class() is None, "tf2_msgs is installed here: the other test covers it"
    node = LoggedNode(ros)
    rp = Replayer(node, path, rate=10.0, clock=False)
    try:
        assert set(rp.publishers) == {"/speed"}
        said = [line for line in node.log.lines if "/tf" in line]
        assert len(said) == 1 and "/tf and /tf_static" in said[0] and "tf2_msgs" in said[0], node.log.lines
        stats = rp.run()
    finally:
        rp.close()
    assert stats.published == {"/speed": 5}
    assert set(stats.skipped_topics) == {"/tf", "/tf_static"}
    assert "/tf_static" in stats.format() and "tf2_msgs is not installed" in stats.format()


def test_with_tf2_msgs_the_replay_republishes_tf_and_latches_tf_static(ros, bag, monkeypatch):
    path, sent = bag
    pkg, msg = types.ModuleType("tf2_msgs"), types.ModuleType("tf2_msgs.msg")
    msg.TFMessage = type("TFMessage", (), {})
    pkg.msg = msg
    monkeypatch.setitem(sys.modules, "tf2_msgs", pkg)
    monkeypatch.setitem(sys.modules, "tf2_msgs.msg", msg)
    tf_derive.tf_message_class.cache_clear()
    try:
        assert tf_derive.tf_message_class() is msg.TFMessage
        node = FakeNode(ros.context)
        rp = Replayer(node, path, rate=10.0, clock=False)
        try:
            stats = rp.run()
        finally:
            rp.close()
    finally:
        tf_derive.tf_message_class.cache_clear()
    assert not stats.skipped_topics and not [line for line in node.log.lines if "/tf" in line]
    assert node.pubs["/tf"].cls is msg.TFMessage and node.pubs["/tf_static"].cls is msg.TFMessage
    # the recorded bytes, unchanged and in order; /tf_static offered latched as tf2's static broadcaster does
    assert {t: p.sent for t, p in node.pubs.items()} == sent
    assert node.pubs["/tf_static"].qos.durability == DurabilityPolicy.TRANSIENT_LOCAL
    assert node.pubs["/tf_static"].qos.depth == 1
    assert node.pubs["/tf"].qos.durability == DurabilityPolicy.VOLATILE
