"""Messages lost before they reach the recorder are counted exactly, over real DDS (localhost, this domain).

A deliberately slow writer (every write delayed) behind a subscription of depth 5 makes the subscription's
KEEP_LAST queue overflow during a burst; the recorder must report exactly the number published and not recorded,
in its summary, in the file's metadata and in ``flagbot bag-summary``.
"""
import json
import struct
import threading
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from flagbot_sim.bag import BagReader
from flagbot_sim.bag.lost import LOST_METADATA_NAME
from flagbot_sim.runs.summary import format_summary, summarize
from flagbot_sim.ros.recorder import Recorder

from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT

TOPIC = "/lost_test/x"


def wait(predicate, timeout, what):
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


def test_a_slow_writer_behind_a_small_queue_loses_messages_and_reports_exactly_how_many(ros, tmp_path,
                                                                                         monkeypatch):
    out = tmp_path / "lost.mcap"
    rec_node = rclpy.create_node("lost_recorder")
    pub_node = rclpy.create_node("lost_publisher")
    executor = SingleThreadedExecutor()
    executor.add_node(rec_node)
    stop = threading.Event()
    spinner = threading.Thread(target=lambda: [executor.spin_once(timeout_sec=0.02) for _ in iter(stop.is_set, True)],
                               daemon=True)
    pub = pub_node.create_publisher(Float64, TOPIC, QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE))
    rec = Recorder(rec_node, out, [TOPIC], depth=5, poll_period=0.05)
    slow = threading.Event()
    real_write = rec.writer.write
    last = [None]

    def slow_write(topic, data, *a, **kw):   # the deliberately slow writer: 2 ms per message in the burst
        if slow.is_set():
            time.sleep(0.002)
        last[0] = struct.unpack_from("<d", bytes(data), 4)[0]     # Float64's CDR: 4-byte header, the double
        return real_write(topic, data, *a, **kw)
    monkeypatch.setattr(rec.writer, "write", slow_write)
    spinner.start()
    try:
        wait(lambda: pub.get_subscription_count() == 1, DISCOVERY_TIMEOUT, "the recorder's subscription")
        # the first message is taken before the burst: counting starts at the first number taken
        pub.publish(Float64(data=0.0))
        wait(lambda: rec.writer.message_count == 1, EVENT_TIMEOUT, "the first message recorded")
        slow.set()
        burst = 3000
        for k in range(1, burst + 1):      # far faster than 2 ms per message: the depth-5 queue overflows
            pub.publish(Float64(data=float(k)))
        # a last message once the recorder has caught up (a loss shows when the next message arrives)
        taken = -1
        while taken != rec.writer.message_count:
            taken = rec.writer.message_count
            time.sleep(0.3)
        slow.clear()
        pub.publish(Float64(data=float(burst + 1)))
        published = burst + 2
        wait(lambda: last[0] == burst + 1, EVENT_TIMEOUT, "the last message recorded")
    finally:
        stop.set()
        spinner.join(5)
        summary = rec.close()
        executor.shutdown()
        rec_node.destroy_node()
        pub_node.destroy_node()
    with BagReader(out) as r:
        values = [int(m.data) for _, _, m in r.decoded(TOPIC)]
        stored = json.loads(r.metadata_named(LOST_METADATA_NAME)["counts"])
    recorded = len(values)
    assert values[0] == 0 and values[-1] == burst + 1 and values == sorted(values)
    lost = published - recorded
    assert lost > 100, (published, recorded)               # the slow writer really lost messages
    assert summary.lost == {TOPIC: lost} and stored == {TOPIC: lost}
    assert f"{lost} messages LOST" in summary.format() and f"{lost} lost" in summary.format()
    s = summarize(out)
    assert s["lost_in_transport"] == lost and [t["lost"] for t in s["topics"]] == [lost]
    assert f"LOST before reaching the recorder: {lost} messages" in format_summary(s)


def test_a_recording_without_losses_says_none_were_lost(ros, tmp_path):
    out = tmp_path / "fine.mcap"
    rec_node = rclpy.create_node("fine_recorder")
    pub_node = rclpy.create_node("fine_publisher")
    pub = pub_node.create_publisher(Float64, TOPIC + "_fine", QoSProfile(depth=100))
    rec = Recorder(rec_node, out, [TOPIC + "_fine"], poll_period=0.05)
    try:
        end = time.monotonic() + DISCOVERY_TIMEOUT
        while pub.get_subscription_count() == 0:
            rclpy.spin_once(rec_node, timeout_sec=0.05)
            assert time.monotonic() < end
        for k in range(50):
            pub.publish(Float64(data=float(k)))
        end = time.monotonic() + EVENT_TIMEOUT
        while rec.writer.message_count < 50:
            rclpy.spin_once(rec_node, timeout_sec=0.05)
            assert time.monotonic() < end
    finally:
        summary = rec.close()
        rec_node.destroy_node()
        pub_node.destroy_node()
    assert summary.lost == {TOPIC + "_fine": 0} and "LOST" not in summary.format()
    s = summarize(out)
    assert s["lost_in_transport"] == 0 and "no message lost before reaching the recorder" in format_summary(s)
