"""The recordings as Foxglove and Lichtblick read them: the npm MCAP reader and ROS 2 CDR decoding under Node.

tests/node/mcap_ros2_read.js opens a file with ``McapIndexedReader`` of ``@mcap/core`` 2.2.2 (the summary: its
statistics, chunk indexes, channels and schemas; then every message through the chunk and message indexes, chunk
CRCs checked), decompresses chunks with ``@mcap/support``'s handlers and decodes each message with
``@foxglove/rosmsg`` 5.0.5 (``parse``, ros2) and ``@foxglove/rosmsg2-serialization`` 3.1.0 (``MessageReader``) from
the ``ros2msg`` schema stored in the file: a client nobody here wrote. The packages are installed from the npm
registry on first use into a cache outside the repository (tests/npm_helpers.py, tests/node/package.json); without
node and npm the tests skip, in CI they fail.

Checked against the Python side: for each committed sample (bags/) the summary's counts and every message's log
time per topic against BagReader, and the decoded values of every 50th message and the last of each topic against
``mcap_ros2``'s decoding; for a file BagWriter writes here (every flagbot message type, a chunk every few
messages) every decoded message against the message that was serialized.
"""
import math
from pathlib import Path

import pytest
from bag_testlib import TOPIC_TYPES, full_topic, make_message, to_plain
from npm_helpers import node_modules, run_node
from rclpy.serialization import serialize_message

from flagbot_sim.bag import BagReader, BagWriter, RunMetadata

ROOT_BAGS = Path(__file__).resolve().parents[1] / "bags"
SAMPLES = sorted(ROOT_BAGS.glob("*.mcap"))
EVERY = 50


@pytest.fixture(scope="module")
def npm():
    return node_modules()


def read_js(path, every: int) -> dict:
    import json
    p = run_node("mcap_ros2_read.js", str(path), str(every), timeout=300.0)
    assert p.returncode == 0, p.stderr
    return json.loads(p.stdout)


def comparable(v):
    """A decoded value as the JavaScript side prints it: JSON has no NaN or infinity (null), and no tuples."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: comparable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [comparable(x) for x in v]
    return v


def test_the_samples_are_committed():
    assert len(SAMPLES) >= 5


@pytest.mark.parametrize("path", SAMPLES, ids=lambda p: p.name)
def test_the_npm_reader_reads_each_sample_as_the_python_reader_does(npm, path):
    js = read_js(path, EVERY)
    with BagReader(path) as r:
        rep = r.report
        types = {t: info.type_name for t, info in r.topics.items()}
        msgs = {}
        for m in r.messages():
            msgs.setdefault(m.topic, []).append(m)
        assert rep.ok and rep.closed
        stats = js["statistics"]
        assert js["profile"] == "ros2"
        assert stats["messageCount"] == rep.messages == sum(len(v) for v in msgs.values())
        assert stats["channelMessageCounts"] == {t: len(v) for t, v in msgs.items()}
        assert js["chunkIndexes"] == stats["chunkCount"] > 0
        assert js["channels"] == types
        assert "flagbot_sim" in js["metadataIndexes"] and "rosbag2" in js["metadataIndexes"]
        assert {t: v["count"] for t, v in js["topics"].items()} == {t: len(v) for t, v in msgs.items()}
        assert int(stats["messageStartTime"]) == min(m.log_time_ns for v in msgs.values() for m in v)
        assert int(stats["messageEndTime"]) == max(m.log_time_ns for v in msgs.values() for m in v)
        for topic, v in msgs.items():
            got = js["topics"][topic]
            assert [int(t) for t in got["logTimes"]] == [m.log_time_ns for m in v], topic
            want = {str(k): comparable(to_plain(r.decode(v[k]))) for k in range(0, len(v), EVERY)}
            want[str(len(v) - 1)] = comparable(to_plain(r.decode(v[-1])))
            assert got["sampled"] == want, topic


def test_the_npm_reader_decodes_every_message_bagwriter_wrote(npm, tmp_path):
    """Every flagbot message type, each field set (bag_testlib.make_message), 60 rounds; a chunk every 3 rounds."""
    path = tmp_path / "fresh.mcap"
    clock = [0.0]
    w = BagWriter(path, metadata=RunMetadata(scene_toml="[robot]\n"), clock=lambda: clock[0], flush_interval=0.025)
    expected = {}
    for name, type_name in TOPIC_TYPES.items():
        w.add_topic(full_topic("/t", name), type_name)
    for k in range(60):
        clock[0] = 0.01 * k
        for i, name in enumerate(TOPIC_TYPES):
            m = make_message(name, k)
            t = 10**12 + 10_000_000 * k + i
            w.write(full_topic("/t", name), serialize_message(m), t)
            expected.setdefault(full_topic("/t", name), []).append((t, comparable(to_plain(m))))
    summary = w.close()
    assert summary.closed and not summary.error
    js = read_js(path, 1)
    assert js["statistics"]["messageCount"] == 60 * len(TOPIC_TYPES)
    assert js["chunkIndexes"] == js["statistics"]["chunkCount"] >= 19
    assert js["channels"] == {full_topic("/t", n): t for n, t in TOPIC_TYPES.items()}
    for topic, v in expected.items():
        got = js["topics"][topic]
        assert [int(t) for t in got["logTimes"]] == [t for t, _ in v]
        assert got["sampled"] == {str(k): m for k, (_, m) in enumerate(v)}, topic
