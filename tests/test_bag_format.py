"""MCAP layout, damaged files and the analysis command — no DDS (messages are serialized in-process)."""
import errno
import io
import json
import shutil
import struct
import sys
from pathlib import Path

import pytest
from bag_testlib import TOPIC_TYPES, full_topic, make_message, read_run, stamp_ns, to_plain
from cli_helpers import flagbot
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_types_from_msg

import flagbot_sim
from flagbot_sim import bag
from flagbot_sim.bag import BagReader, BagWriter, NotMcapError, RunMetadata, recover, scan

SHARE = Path(sys.prefix) / "share"
ROOT_BAGS = Path(__file__).resolve().parents[1] / "bags"


class FakeClock:
    """The writer's monotonic clock, advanced by the test: flushes then happen at known message indices."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


def write_stream_bag(target, n=1000, rate=100.0, **kw):
    """n Float64 messages (data = index) at `rate` Hz of log time; the writer's clock follows the log time."""
    from std_msgs.msg import Float64
    clock = FakeClock()
    w = BagWriter(target, clock=clock, metadata=RunMetadata(scene_toml="[robot]\nn_flagella = 2\n"), **kw)
    w.add_topic("/t/omega_h", "std_msgs/msg/Float64")
    t0 = 1_000_000_000_000
    for k in range(n):
        clock.t = k / rate
        w.write("/t/omega_h", serialize_message(Float64(data=float(k))), t0 + int(k * 1e9 / rate))
    return w


def values(path):
    with BagReader(path) as r:
        return [int(r.decode(m).data) for m in r.messages()]


# ----------------------------------------------------------------------------------------------------------------
# layout


def test_joint_state_schema_is_rosbag2s_full_definition():
    """rosbag2 stores the .msg text, then each dependency after 80 '=' and 'MSG: pkg/Type', depth first."""
    text = lambda p: (SHARE / p).read_text()  # noqa: E731
    sep = "=" * 80 + "\n"
    expected = (text("sensor_msgs/msg/JointState.msg") + "\n" + sep + "MSG: std_msgs/Header\n"
                + text("std_msgs/msg/Header.msg") + "\n" + sep + "MSG: builtin_interfaces/Time\n"
                + text("builtin_interfaces/msg/Time.msg"))
    assert bag.message_definition("sensor_msgs/msg/JointState") == expected


@pytest.mark.parametrize("type_name", sorted(set(TOPIC_TYPES.values())))
def test_every_flagbot_schema_parses_in_both_readers_and_lists_each_dependency_once(type_name):
    text = bag.message_definition(type_name)
    deps = [line[5:] for line in text.splitlines() if line.startswith("MSG: ")]
    assert len(deps) == len(set(deps))
    for i, line in enumerate(text.splitlines()):
        if line.startswith("MSG: "):
            assert text.splitlines()[i - 1] == "=" * 80
    assert type_name in generate_dynamic_names(type_name, text)
    types = get_types_from_msg(text, type_name)     # rosbags' parser
    assert type_name in types and all(f"{d.split('/')[0]}/msg/{d.split('/')[-1]}" in types for d in deps)


def generate_dynamic_names(type_name, text):
    from mcap_ros2._dynamic import generate_dynamic
    return set(generate_dynamic(type_name, text))


def test_writer_layout_timing_and_metadata(tmp_path):
    """Profile ros2, schemas ros2msg named pkg/msg/Type, channels cdr with QoS, publish time = header stamp,
    the run metadata (scene, parameters, version) and rosbag2's own metadata record."""
    path = tmp_path / "layout.mcap"
    params = {"dt": 0.01, "omega_T": 10.5, "n_flagella": 3, "frame": "world", "gains": [1.0, 2.0]}
    scene = (Path(flagbot_sim.__file__).parent / "scenes" / "design1.toml").read_text()
    w = BagWriter(path, metadata=RunMetadata(scene_toml=scene, parameters=params, extra={"operator": "ci"}))
    qos = bag.qos_to_yaml([bag.QosInfo(durability="transient_local", depth=1)])
    expected = {}
    for name, type_name in TOPIC_TYPES.items():
        w.add_topic(full_topic("/t", name), type_name, offered_qos_profiles=qos)
    for k in range(5):
        for name in TOPIC_TYPES:
            m = make_message(name, k)
            log = 2_000_000_000_000 + 10_000_000 * k
            w.write(full_topic("/t", name), serialize_message(m), log)
            expected.setdefault(full_topic("/t", name), []).append((to_plain(m), log, stamp_ns(m) or log))
    summary = w.close()
    assert summary.closed and summary.messages == 35

    with open(path, "rb") as f:
        r = make_reader(f, decoder_factories=[DecoderFactory()])
        assert r.get_header().profile == "ros2"
        s = r.get_summary()
        assert s.statistics.message_count == 35 and s.chunk_indexes
        assert {sc.name for sc in s.schemas.values()} == set(TOPIC_TYPES.values())
        assert all(sc.encoding == "ros2msg" for sc in s.schemas.values())
        assert all(ch.message_encoding == "cdr" for ch in s.channels.values())
        got = {}
        for _, ch, msg, dec in r.iter_decoded_messages():
            got.setdefault(ch.topic, []).append((to_plain(dec), msg.log_time, msg.publish_time))
        meta = {m.name: m.metadata for m in r.iter_metadata()}
    assert got == expected
    assert "version: 9" in meta["rosbag2"]["serialized_metadata"]
    rm = RunMetadata.from_record(meta["flagbot_sim"])
    assert rm.scene_toml == scene and rm.parameters == params and rm.extra == {"operator": "ci"}
    assert rm.package_version == flagbot_sim.__version__
    with AnyReader([path]) as ar:           # rosbags parses the QoS strings and counts everything
        assert ar.message_count == 35
        q = {c.topic: c.ext.offered_qos_profiles[0] for c in ar.connections}
        assert q["/t/odom"].durability.name == "TRANSIENT_LOCAL" and q["/t/odom"].depth == 1


# ----------------------------------------------------------------------------------------------------------------
# damage


def test_truncation_anywhere_recovers_exactly_the_complete_chunks(tmp_path):
    """A file cut at any byte (kill -9, full disk) yields every message of every chunk written completely before
    the cut, never raises, says it was not closed, and recover() turns it into a valid file for other readers."""
    src = tmp_path / "full.mcap"
    w = write_stream_bag(src)
    assert w.close().closed
    data = src.read_bytes()
    found = _chunks(src)
    chunks = [c for c, _ in found]
    assert len(chunks) >= 15     # 10 s at a 0.5 s flush interval

    counts = [n for _, n in found]
    cuts = sorted({20, 200, 600} | {len(data) * i // 37 for i in range(1, 37)} | {len(data) - 1, len(data) - 40})
    cut_file = tmp_path / "cut.mcap"
    previous = -1
    for cut in cuts:
        cut_file.write_bytes(data[:cut])
        rep = scan(cut_file)
        expected = sum(n for c, n in zip(chunks, counts) if c.chunk_start_offset + c.chunk_length <= cut)
        assert rep.messages == expected, f"cut at {cut}"
        assert values(cut_file) == list(range(expected))
        assert not rep.closed and not rep.ok and "not closed properly" in rep.describe_loss()
        assert rep.messages >= previous
        previous = rep.messages
    # the last cut (inside the footer) keeps everything; the recovered file is valid for mcap and rosbags
    out = tmp_path / "recovered.mcap"
    cut_file.write_bytes(data[: len(data) * 20 // 37])
    rep = recover(cut_file, out)
    with open(out, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == rep.messages > 0
    with AnyReader([out]) as ar:
        assert ar.message_count == rep.messages
    assert scan(out).ok
    assert BagReader(out).metadata_named("flagbot_sim.recovery")["recovered_messages"] == str(rep.messages)
    assert BagReader(out).run_metadata().scene_toml == "[robot]\nn_flagella = 2\n"


def _chunks(path):
    """(chunk index, number of messages in the chunk) of an intact file, in file order."""
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk
    with open(path, "rb") as f:
        indexes = make_reader(f).get_summary().chunk_indexes
    with open(path, "rb") as f:
        counts = [sum(isinstance(r, Message) for r in breakup_chunk(c))
                  for c in StreamReader(f, emit_chunks=True).records if isinstance(c, Chunk)]
    assert len(indexes) == len(counts)
    return list(zip(sorted(indexes, key=lambda c: c.chunk_start_offset), counts))


@pytest.mark.parametrize("damage", ["data-byte", "length-field", "opcode", "zeroed-block", "first-chunk"])
def test_corrupt_chunk_loses_only_that_chunk_and_says_so(tmp_path, damage):
    src = tmp_path / "full.mcap"
    write_stream_bag(src).close()
    data = bytearray(src.read_bytes())
    chunks = _chunks(src)
    # the first chunk also carries the schema and channel; they are written outside chunks too, so later
    # chunks stay decodable without it
    c, n_lost = chunks[0 if damage == "first-chunk" else 7]
    damage = "data-byte" if damage == "first-chunk" else damage
    start = c.chunk_start_offset
    if damage == "data-byte":
        data[start + c.chunk_length - 20] ^= 0x55          # inside the compressed data: CRC/decompression fails
    elif damage == "length-field":
        data[start + 5] ^= 0x40                              # record length now points far past the file end
    elif damage == "opcode":
        data[start] = 0x7E
    else:                                                    # a zeroed 4 KiB block (bad sector) over the chunk
        data[start:start + 4096] = bytes(min(4096, len(data) - start))
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    rep = scan(bad)
    lost_chunks = [k for k, (ck, _) in enumerate(chunks)
                   if ck.chunk_start_offset < start + (4096 if damage == "zeroed-block" else 1)
                   and ck.chunk_start_offset + ck.chunk_length > start]
    n_expected_lost = sum(chunks[k][1] for k in lost_chunks)
    assert n_expected_lost >= n_lost > 0
    assert rep.messages == 1000 - n_expected_lost
    assert rep.lost_messages == n_expected_lost            # exact: the summary survived
    assert rep.closed and not rep.ok and rep.damage[0].offset == start
    text = rep.describe_loss()
    assert f"{n_expected_lost} of 1000 messages lost" in text and f"at byte {start}" in text
    got = values(bad)
    lost_values = set(range(1000)) - set(got)
    assert got == sorted(got) and len(lost_values) == n_expected_lost
    if damage == "data-byte":
        assert rep.damage[0].kind == "corrupt-chunk"
        lo, hi = (rep.damage[0].log_start_ns - 1e12) / 1e7, (rep.damage[0].log_end_ns - 1e12) / 1e7
        assert lost_values == set(range(round(lo), round(hi) + 1))   # the reported time range is the lost one


class FullDisk(io.RawIOBase):
    """A disk with room for ``limit`` bytes: writes past it fail with ENOSPC (after writing what fits)."""

    def __init__(self, limit):
        self.buf, self.limit = bytearray(), limit

    def writable(self):
        return True

    def write(self, b):
        room = self.limit - len(self.buf)
        if room <= 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.buf += bytes(b[:room])
        if len(b) > room:
            raise OSError(errno.ENOSPC, "No space left on device")
        return len(b)

    def tell(self):
        return len(self.buf)


def test_writer_refuses_a_target_it_cannot_write_and_leaves_nothing_behind(tmp_path):
    """No such directory (not created either), a path the OS refuses, an existing file, a disk already full, a
    reserved metadata key: a BagWriteError (an OSError and a BagError) or BagError from the constructor, and no
    new file."""
    from flagbot_sim.bag import BagError, BagWriteError
    existing = tmp_path / "taken.mcap"
    existing.write_bytes(b"keep me")
    for target, why in ((tmp_path / "missing" / "run.mcap", "does not exist"), ("/proc/flagbot_run.mcap", "ENOENT"),
                        (existing, "exists"), (FullDisk(40), "No space left on device (ENOSPC)")):
        with pytest.raises(BagWriteError) as exc:
            BagWriter(target, metadata=RunMetadata())
        assert isinstance(exc.value, OSError) and isinstance(exc.value, BagError) and why in str(exc.value)
    assert not (tmp_path / "missing").exists() and not Path("/proc/flagbot_run.mcap").exists()
    assert existing.read_bytes() == b"keep me"
    with pytest.raises(BagError, match="reserved"):
        BagWriter(tmp_path / "meta.mcap", metadata=RunMetadata(extra={"parameters": "x"}))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.mcap"]


def test_a_message_is_flushed_at_most_one_flush_interval_after_it_was_written(tmp_path):
    """The flush policy behind the crash-loss bound: a chunk closes when the interval has passed since the last
    flush, whether the next write or the recorder's flush thread (maybe_flush at seconds_to_flush) notices; a
    quiet spell restarts the interval instead of flushing a lone message at once."""
    from std_msgs.msg import Float64
    assert bag.DEFAULT_FLUSH_INTERVAL == 0.1
    clock, disk = FakeClock(), FullDisk(10**9)
    w = BagWriter(disk, clock=clock)
    w.add_topic("/t/omega_h", "std_msgs/msg/Float64")
    header = len(disk.buf)
    assert w.seconds_to_flush() == pytest.approx(0.1)
    clock.t = 5.0                                    # idle for 5 s: nothing to flush, the interval starts again
    w.maybe_flush()
    assert len(disk.buf) == header and w.seconds_to_flush() == pytest.approx(0.1)
    clock.t = 5.03
    w.write("/t/omega_h", serialize_message(Float64(data=1.0)), 10**12)
    assert len(disk.buf) == header                   # in the open chunk
    assert w.seconds_to_flush() == pytest.approx(0.07)
    clock.t = 5.09
    w.maybe_flush()
    assert len(disk.buf) == header                   # not due yet
    clock.t = 5.1 + 1e-9
    w.maybe_flush()
    assert len(disk.buf) > header                    # on disk 0.07 s after it was written
    assert w.seconds_to_flush() == pytest.approx(0.1)
    # a 100 Hz stream: one chunk per 0.1 s (10 or 11 messages), never more than the interval's worth in one
    path = tmp_path / "stream.mcap"
    write_stream_bag(path, n=1000).close()
    counts = [n for _, n in _chunks(path)]
    assert sum(counts) == 1000 and max(counts) <= 11 and len(counts) >= 90


def test_full_disk_stops_recording_and_keeps_what_was_flushed(tmp_path):
    """ENOSPC in the middle of a chunk: no exception into the node, `error` says what happened, and all but the
    last flush interval is recoverable."""

    disk = FullDisk(12_000)
    w = write_stream_bag(disk, n=1000)
    assert w.error and "No space left on device" in w.error
    failed_at = w.message_count
    assert 0 < failed_at < 1000
    assert w.write("/t/omega_h", b"\0\1\0\0" + bytes(8), 1) is False
    summary = w.close()                                     # must not raise
    assert not summary.closed and summary.error
    damaged = tmp_path / "disk_full.mcap"
    damaged.write_bytes(bytes(disk.buf))
    got = values(damaged)
    assert got == list(range(len(got)))
    assert failed_at - len(got) <= 51                       # at most one flush interval (0.5 s at 100 Hz) lost
    assert "not closed properly" in scan(damaged).describe_loss()


@pytest.mark.parametrize("content, what", [(b"hello world\n", "starts with b'hello wo'"),
                                           (b"", "the file is empty"),
                                           (b"SQLite format 3\0" + bytes(100), "SQLite database"),
                                           (b"#ROSBAG V2.0\n" + bytes(50), "ROS 1 bag")])
def test_non_mcap_file_gets_a_clear_error(tmp_path, content, what):
    p = tmp_path / "run.mcap"
    p.write_bytes(content)
    with pytest.raises(NotMcapError) as exc:
        BagReader(p)
    assert "is not an MCAP file" in str(exc.value) and what in str(exc.value)


def test_cli_non_mcap_and_damaged_files(tmp_path):
    p = tmp_path / "notes.txt"
    p.write_text("not a recording")
    for cmd in (["bag-summary", str(p)], ["replay", str(p)], ["bag-recover", str(p)]):
        r = flagbot(*cmd)
        assert r.returncode == 2, r.stderr
        assert "is not an MCAP file" in r.stderr and "Traceback" not in r.stderr
    src = tmp_path / "ok.mcap"
    write_stream_bag(src, n=300).close()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(src.read_bytes()[:3000])
    r = flagbot("bag-summary", str(cut))
    assert r.returncode == 0 and "NOT closed properly" in r.stdout and "LOST:" in r.stdout
    r = flagbot("bag-recover", str(cut), "-o", str(tmp_path / "fixed.mcap"))
    assert r.returncode == 0 and "valid and indexed" in r.stdout
    assert scan(tmp_path / "fixed.mcap").ok


def test_a_rosbag2_directory_opens_its_mcap(tmp_path):
    d = tmp_path / "run_0"
    d.mkdir()
    write_stream_bag(d / "run_0_0.mcap", n=10).close()
    (d / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    assert scan(d).messages == 10


# ----------------------------------------------------------------------------------------------------------------
# analysis


def write_step_bag(path, with_clock=True, parameters=None):
    """A synthetic run: omega_T 10 (from the scene) -> 5 -> 10 -> 10 (repeat) -> 15 rad/s; omega_h = 0.3 omega_T,
    omega_t = 0.7 omega_T, v = 1e-3 omega_T, each approached with a 0.1 s time constant. Simulation time runs
    twice as fast as log time and is recorded on /clock."""
    import math

    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import Float64
    scene = "[motor]\nomega_rpm = %r\n" % (10.0 / (2 * math.pi / 60))
    w = BagWriter(path, metadata=RunMetadata(scene_toml=scene, parameters=parameters or {"rate": 100}))
    for t in ("/bot/cmd_omega", "/bot/omega_h", "/bot/omega_t", "/bot/speed", "/bot/beam/omega_h"):
        w.add_topic(t, "std_msgs/msg/Float64")
    if with_clock:
        w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    T0 = 3_000_000_000_000
    log = lambda ts: T0 + int(ts / 2 * 1e9)  # noqa: E731  (sim time -> log time: sim runs 2x real time)
    cmds = [(1.0, 5.0), (3.0, 10.0), (4.0, 10.0), (6.0, 15.0)]
    w_now, y = 10.0, {"h": 3.0, "t": 7.0, "v": 0.01}
    ci = 0
    for k in range(0, 901):
        ts = k * 0.01
        while ci < len(cmds) and cmds[ci][0] <= ts + 1e-9:
            w.write("/bot/cmd_omega", serialize_message(Float64(data=cmds[ci][1])), log(ts))
            w_now = cmds[ci][1]
            ci += 1
        a = 1 - math.exp(-0.01 / 0.1)
        y = {"h": y["h"] + a * (0.3 * w_now - y["h"]), "t": y["t"] + a * (0.7 * w_now - y["t"]),
             "v": y["v"] + a * (1e-3 * w_now - y["v"])}
        if with_clock:
            c = Clock()
            c.clock.sec, c.clock.nanosec = divmod(int(round(ts * 1e9)), 1_000_000_000)
            w.write("/clock", serialize_message(c), log(ts))
        w.write("/bot/omega_h", serialize_message(Float64(data=y["h"])), log(ts))
        w.write("/bot/omega_t", serialize_message(Float64(data=y["t"])), log(ts))
        w.write("/bot/speed", serialize_message(Float64(data=y["v"])), log(ts))
        w.write("/bot/beam/omega_h", serialize_message(Float64(data=-1.0)), log(ts))
    w.close()


def test_bag_summary_finds_the_steps_and_their_steady_state(tmp_path):
    from flagbot_sim.runs.summary import summarize
    path = tmp_path / "steps.mcap"
    write_step_bag(path)
    s = summarize(path)
    assert s["time_axis"] == "sim" and s["namespace"] == "/bot"
    steps = s["steps"]
    # the scene's speed until the first command, then one step per change (the repeated 10 is not a step)
    assert [(st["source"], st["omega_T"]) for st in steps] == [("initial", pytest.approx(10.0)), ("cmd_omega", 5.0),
                                                               ("cmd_omega", 10.0), ("cmd_omega", 15.0)]
    assert [st["t_start"] for st in steps] == pytest.approx([0.0, 1.0, 3.0, 6.0], abs=1e-6)   # simulated seconds
    for st in steps:   # steady values, not the beam/ topic of the same name, not the transient
        assert st["omega_h"] == pytest.approx(0.3 * st["omega_T"], rel=1e-3)
        assert st["omega_t"] == pytest.approx(0.7 * st["omega_T"], rel=1e-3)
        assert st["v"] == pytest.approx(1e-3 * st["omega_T"], rel=1e-3)
    s_log = summarize(path, time_axis="log")
    assert [st["t_start"] for st in s_log["steps"]] == pytest.approx([0.0, 0.5, 1.5, 3.0], abs=1e-6)
    # the sim_node's initial_omega parameter, when recorded, is the speed before the first command
    write_step_bag(tmp_path / "param.mcap", parameters={"initial_omega": 2.0})
    assert summarize(tmp_path / "param.mcap")["steps"][0]["omega_T"] == 2.0


def test_bag_summary_cli_prints_json_and_writes_the_plot(tmp_path):
    path = tmp_path / "steps.mcap"
    write_step_bag(path, with_clock=False)
    png = tmp_path / "plot.png"
    r = flagbot("bag-summary", str(path), "--json", "--plot", str(png))
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["time_axis"] == "log" and len(out["steps"]) == 4 and out["messages"] == 4 + 4 * 901
    assert {t["topic"]: t["count"] for t in out["topics"]}["/bot/speed"] == 901
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    r = flagbot("bag-summary", str(path))
    assert r.returncode == 0 and "omega_T steps" in r.stdout and "/bot/cmd_omega" in r.stdout


def test_bag_summary_plot_says_what_its_shaded_windows_are(tmp_path):
    from flagbot_sim.runs.summary import summarize, summary_figure
    path = tmp_path / "steps.mcap"
    write_step_bag(path)
    fig = summary_figure(summarize(path, tail=0.4))
    texts = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "steady window: the last 40 % of each omega_T step" in texts
    assert "steady value: mean over the window" in texts and "omega_T step (new command)" in texts
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_bag_summary_with_nothing_recoverable_exits_non_zero_with_a_message(tmp_path):
    """A recording killed before its first message was flushed, and an empty but intact one: no table that looks
    like success, but an error naming the file (and, for the damaged one, what was lost)."""
    from std_msgs.msg import Float64
    killed = tmp_path / "killed.mcap"
    w = BagWriter(tmp_path / "writing.mcap", metadata=RunMetadata(scene_toml="[robot]\n"))
    w.add_topic("/t/omega_h", "std_msgs/msg/Float64")
    w.flush()                                               # header, metadata, schema, channel on disk; no message
    killed.write_bytes((tmp_path / "writing.mcap").read_bytes())
    w.write("/t/omega_h", serialize_message(Float64(data=1.0)), 10**12)
    w.close()
    empty = tmp_path / "empty.mcap"
    BagWriter(empty).close()
    for path, why, extra in ((killed, "not closed properly", []), (empty, "holds no message", ["--json"])):
        r = flagbot("bag-summary", str(path), *extra)
        assert r.returncode != 0 and r.stdout == "", (path, r.stdout)
        assert r.stderr.startswith("error: ") and str(path) in r.stderr and why in r.stderr, r.stderr
        assert "Traceback" not in r.stderr
    assert scan(killed).messages == 0 and scan(empty).ok
    # bag-recover says the same (it wrote an empty "valid and indexed" file and exited 0)
    r = flagbot("bag-recover", str(killed), "-o", str(tmp_path / "out.mcap"))
    assert r.returncode == 2 and "nothing recoverable" in r.stderr and not (tmp_path / "out.mcap").exists()


def test_read_run_gives_what_a_resimulation_needs(tmp_path):
    path = tmp_path / "steps.mcap"
    write_step_bag(path)
    run = read_run(path)
    assert run.parameters == {"rate": 100} and "omega_rpm" in run.scene_toml
    assert [c[2] for c in run.cmd_omega] == [5.0, 10.0, 10.0, 15.0]
    assert [c[1] for c in run.cmd_omega] == pytest.approx([1.0, 3.0, 4.0, 6.0], abs=1e-6)   # sim time
    assert [c[0] for c in run.cmd_omega] == pytest.approx([0.5, 1.5, 2.0, 3.0], abs=1e-6)   # log time


def test_cdr_header_stamp_is_read_without_decoding():
    m = make_message("joint_states", 3)
    assert bag.cdr_header_stamp_ns(serialize_message(m)) == stamp_ns(m)
    assert bag.has_header("sensor_msgs/msg/JointState") and not bag.has_header("visualization_msgs/msg/MarkerArray")
    assert struct.unpack_from("<i", serialize_message(m), 4)[0] == 103


def test_recording_to_a_directory_fifo_or_device_is_refused_and_writes_nothing_beside_it(tmp_path):
    """record:=/tmp was accepted and wrote /tmp.mcap (the missing suffix is appended); a directory, FIFO or
    device is now refused by name, and nothing is created next to it."""
    import os
    from flagbot_sim.bag.writer import BagWriteError, BagWriter
    d = tmp_path / "runs"
    d.mkdir()
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    for target, words in ((d, "is a directory"), (fifo, "not a regular file"), ("/dev/null", "not a regular file")):
        with pytest.raises(BagWriteError) as err:
            BagWriter(target)
        assert words in str(err.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pipe", "runs"] and not list(d.iterdir())
    assert not os.path.exists("/dev/null.mcap")


def test_writer_refuses_a_symbolic_link_to_a_missing_or_irregular_target_and_never_follows_one(tmp_path,
                                                                                               monkeypatch):
    """A dangling link (at the name given or at the '.mcap' name made of it) would create its target elsewhere; a
    link to a directory or FIFO is no regular file: all refused by name, nothing created. Without overwrite the
    file is opened O_EXCL ("xb"), so a link made after the checks (a race) is refused too, its target untouched."""
    import os
    from flagbot_sim.bag.writer import BagWriteError
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    target = elsewhere / "target.mcap"
    fifo = elsewhere / "pipe"
    os.mkfifo(fifo)
    (tmp_path / "link.mcap").symlink_to(target)
    (tmp_path / "bare").symlink_to(target)
    (tmp_path / "run.mcap").symlink_to(target)
    (tmp_path / "dir.mcap").symlink_to(elsewhere)
    (tmp_path / "fifo.mcap").symlink_to(fifo)
    for name, words in (("link.mcap", "which does not exist"), ("bare", "which does not exist"),
                        ("run", "which does not exist"), ("dir.mcap", "not a regular file"),
                        ("fifo.mcap", "not a regular file")):
        for overwrite in (False, True):
            with pytest.raises(BagWriteError) as err:
                BagWriter(tmp_path / name, overwrite=overwrite)
            assert "symbolic link" in str(err.value) and words in str(err.value), (name, str(err.value))
            assert str(tmp_path) in str(err.value)
    assert sorted(p.name for p in elsewhere.iterdir()) == ["pipe"]
    # the race: the checks pass, then a link appears before the open
    import builtins

    from flagbot_sim.bag import writer as writer_module
    race = tmp_path / "race.mcap"

    def link_appears(file, mode="r", *a, **kw):
        if Path(file) == race:
            race.symlink_to(target)
        return builtins.open(file, mode, *a, **kw)
    monkeypatch.setattr(writer_module, "open", link_appears, raising=False)
    with pytest.raises(BagWriteError, match="File exists"):
        BagWriter(race)
    assert not target.exists()
    monkeypatch.undo()
    # a link to an existing regular file is that file: refused as existing, replaced only with overwrite
    target.write_bytes(b"keep me")
    with pytest.raises(BagWriteError, match="it exists"):
        BagWriter(tmp_path / "link.mcap")
    assert target.read_bytes() == b"keep me"
    BagWriter(tmp_path / "link.mcap", overwrite=True).close()
    assert target.read_bytes().startswith(bag.format.MCAP_MAGIC)


def test_bag_recover_writes_small_chunks_so_a_flipped_bit_anywhere_loses_at_most_one(tmp_path, monkeypatch):
    """bag-recover wrote a single chunk: one flipped bit of the recovered file usually lost everything on a second
    recovery. It now writes chunks of at most 0.1 s of log time, with CRCs and the schemas and channels also
    outside chunks; a single-bit flip at any of many seeded random positions of a recovered real recording loses
    at most one chunk's messages, and the report counts the loss exactly, even when the summary is the part hit
    (the recovered file states its message count at its start)."""
    import random
    from mcap.reader import make_reader as mk
    # the recovered file names its source: the same relative name on every checkout gives the same bytes, so the
    # seeded flips below hit the same records everywhere
    monkeypatch.chdir(tmp_path)
    shutil.copyfile(ROOT_BAGS / "design2_n2_steps.mcap", "src.mcap")
    rec = tmp_path / "rec.mcap"
    rep = recover("src.mcap", rec)
    n = rep.messages
    assert scan(rec).ok and scan(rec).messages == n > 1000
    with open(rec, "rb") as f:
        summary = mk(f).get_summary()
    chunks = summary.chunk_indexes
    duration = (rep.end_ns - rep.start_ns) * 1e-9
    assert len(chunks) >= duration / 0.1 * 0.9, (len(chunks), duration)
    assert all(c.message_end_time - c.message_start_time < 0.1e9 for c in chunks)
    biggest = max(_messages_in_chunks(rec))
    assert sum(_messages_in_chunks(rec)) == n and biggest < n / 20
    data = rec.read_bytes()
    rng = random.Random(20_5)
    flipped = tmp_path / "flipped.mcap"
    worst = 0
    for _ in range(120):
        pos, bit = rng.randrange(len(data)), rng.randrange(8)
        d = bytearray(data)
        d[pos] ^= 1 << bit
        flipped.write_bytes(bytes(d))
        again = scan(flipped)
        lost = n - again.messages
        assert 0 <= lost <= biggest, (pos, bit, again.describe_loss())
        assert again.lost_messages == lost, (pos, bit, again.describe_loss())
        if lost:
            assert f"{lost} of {n} messages lost" in again.describe_loss()
        worst = max(worst, lost)
    assert worst > 0                       # some flips did hit a chunk's data
    # every bit of one message index's opcode and length (a flip there once sent the walk past two good chunks,
    # another turned the index into a data end and lost every chunk after it)
    index_at = next(off for off in range(len(data) - 9) if data[off] == 0x07 and
                    off > chunks[len(chunks) // 2].chunk_start_offset + chunks[len(chunks) // 2].chunk_length - 1)
    for byte in range(index_at, index_at + 9):
        for bit in range(8):
            d = bytearray(data)
            d[byte] ^= 1 << bit
            flipped.write_bytes(bytes(d))
            again = scan(flipped)
            assert 0 <= n - again.messages <= biggest and again.lost_messages == n - again.messages, \
                (byte - index_at, bit, again.describe_loss())
    # a flip in the summary: the count stated at the start still makes the loss exact (0 here)
    d = bytearray(data)
    d[_summary_start(data)] ^= 0x40             # the opcode of the summary's first record: nothing after it is read
    flipped.write_bytes(bytes(d))
    again = scan(flipped)
    assert again.summary_messages is None and again.lost_messages == 0 and again.messages == n
    # and the CLI: a flipped chunk, the second recovery's report line says how many messages were lost
    d = bytearray(data)
    c = chunks[len(chunks) // 2]
    d[c.chunk_start_offset + c.chunk_length - 100] ^= 0x04
    flipped.write_bytes(bytes(d))
    r = flagbot("bag-recover", str(flipped), "-o", str(tmp_path / "again.mcap"), timeout=120)
    lost = n - scan(tmp_path / "again.mcap").messages
    assert r.returncode == 0 and 0 < lost <= biggest, r.stdout + r.stderr
    assert f"{lost} of {n} messages lost" in r.stdout, r.stdout


def _messages_in_chunks(path):
    from mcap.records import Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk
    with open(path, "rb") as f:
        return [sum(isinstance(r, Message) for r in breakup_chunk(c))
                for c in StreamReader(f, emit_chunks=True).records if isinstance(c, Chunk)]


def test_a_corrupt_chunk_is_counted_from_its_message_indexes_when_the_summary_is_gone_too(tmp_path):
    """Two damages, a chunk and the summary: the messages the lost chunk held are still counted exactly, from the
    message index records the writer put after it."""
    src = tmp_path / "full.mcap"
    write_stream_bag(src).close()
    data = bytearray(src.read_bytes())
    chunks = _chunks(src)
    c, n_lost = chunks[5]
    data[c.chunk_start_offset + c.chunk_length - 20] ^= 0x55
    data[_summary_start(bytes(data))] = 0x7E      # the first summary record's opcode: the summary is unreadable
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    rep = scan(bad)
    assert rep.summary_messages is None and rep.messages == 1000 - n_lost
    assert rep.damage[0].messages == n_lost and rep.lost_messages == n_lost
    assert f"{n_lost} of 1000 messages lost" in rep.describe_loss()


def _summary_start(data: bytes) -> int:
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)   # the footer's first field
    return summary_start
