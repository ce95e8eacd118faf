"""The recorder when its file cannot be written: refused up front, or one clear error and a non-zero exit.

A full disk is tested honestly in a child process that may not write past a file size limit (RLIMIT_FSIZE: the
write fails with EFBIG, as it would with ENOSPC on a full disk); the standalone recorder and a Recorder inside a
node (how sim_node's `record` parameter uses it) both run that way, as users start them.
"""
import json
import os
import signal

from bag_testlib import DISCOVERY_TIMEOUT, ChildProcess, limited, start_helper, wait_for

from flagbot_sim.bag import BagReader, scan

TESTLIB = os.path.join(os.path.dirname(os.path.abspath(__file__)), "bag_testlib.py")


def results(output: str) -> list[dict]:
    return [json.loads(line) for line in output.splitlines() if line.startswith("{")]


def test_recorder_refuses_a_target_it_cannot_write_before_creating_anything(tmp_path):
    """Recorder(node, path, topics, meta) raises an OSError (which is also a BagError) naming the problem, leaves
    no file or directory behind and adds no subscription or timer to the node; a good path works."""
    existing = tmp_path / "taken.mcap"
    existing.write_bytes(b"keep me")
    paths = [str(tmp_path / "no_such_dir" / "run.mcap"), "/proc/flagbot_test_run.mcap", str(existing),
             str(tmp_path / "good.mcap")]
    p = start_helper("openfail", *[a for path in paths for a in ("--out", path)])
    code, output = p.wait(timeout=DISCOVERY_TIMEOUT + 20)
    assert code == 0, output
    got = {r["path"]: r for r in results(output)}
    missing, proc, taken, good = (got[path] for path in paths)
    for r, why in ((missing, "directory " + str(tmp_path / "no_such_dir") + " does not exist"),
                   (proc, "/proc/flagbot_test_run.mcap"), (taken, "exists")):
        assert r["raised"] == "BagWriteError" and r["oserror"] and r["bagerror"], r
        assert why in r["message"] and r["new_entities"] == 0, r
    assert not missing["left_behind"] and not (tmp_path / "no_such_dir").exists()
    assert not proc["left_behind"]
    assert existing.read_bytes() == b"keep me"
    assert good["raised"] is None and scan(tmp_path / "good.mcap").ok


def test_recorder_on_a_full_disk_at_open_raises_and_leaves_no_file(tmp_path):
    """The header and metadata are flushed by the constructor, so a disk that is already full fails there."""
    out = tmp_path / "full.mcap"
    p = limited(400, TESTLIB, "openfail", "--out", str(out))
    code, output = p.wait(timeout=DISCOVERY_TIMEOUT + 20)
    assert code == 0, output
    (r,) = results(output)
    assert r["raised"] == "BagWriteError" and r["oserror"] and r["bagerror"], r
    assert "File too large (EFBIG)" in r["message"] and r["new_entities"] == 0
    assert not r["left_behind"] and not out.exists()


def test_recorder_in_a_node_sets_its_error_once_and_keeps_it_until_closed(tmp_path):
    """The sim_node's use, under a file size limit: `error` is '' while healthy, then the first failure; nothing is
    written after it although messages keep arriving; it is logged once; close() returns it in its summary."""
    out = tmp_path / "self.mcap"
    p = limited(40_000, TESTLIB, "fullself", "--ns", "/t", "--out", str(out))
    code, output = p.wait(timeout=DISCOVERY_TIMEOUT + 60)
    assert code == 0, output
    r = json.loads(output.split("RESULT ", 1)[1].splitlines()[0])
    assert r["error_at_start"] == ""
    assert "File too large (EFBIG)" in r["first_error"] and str(out) in r["first_error"]
    assert r["later_error"] == r["first_error"] == r["summary_error"]
    assert r["published"] > r["published_at_error"] and r["written_later"] == r["written_at_error"]
    assert not r["summary_closed"] and r["summary_messages"] == r["written_at_error"]
    assert output.count("recording stopped") == 1, output
    assert os.path.getsize(out) <= 40_000
    with BagReader(out) as rd:               # what was flushed before the disk filled is there, in order
        got = [int(rd.decode(m).data) for m in rd.messages()]
    assert got and got == sorted(got) and len(got) <= r["written_at_error"]


def test_standalone_record_on_a_full_disk_logs_one_error_and_exits_non_zero(tmp_path):
    out = str(tmp_path / "full.mcap")
    log = str(tmp_path / "stream.log")
    rec = limited(64_000, "-m", "flagbot_sim.ros.recorder", "-o", out, "/t/omega_h")
    pub = start_helper("stream", "--topic", "/t/omega_h", "--rate", "2000", "--log", log)
    try:
        wait_for(lambda: "recording stopped" in rec.output(), DISCOVERY_TIMEOUT + 30, "the write failure", rec)
        code, output = rec.stop(signal.SIGINT)
    finally:
        pub.stop()
        rec.kill()
    assert code == 1, output
    assert output.count("recording stopped") == 1, output             # one clear error, not one per message
    assert "File too large (EFBIG)" in output and "ERROR: writing" in output and "NOT closed" in output
    assert "Traceback" not in output
    written = int(output.split(f"{out}: ", 1)[1].split(" messages")[0])
    fixed = tmp_path / "fixed.mcap"
    r = ChildProcess("-m", "flagbot_sim", "bag-recover", out, "-o", str(fixed))
    code, text = r.wait(timeout=DISCOVERY_TIMEOUT)
    assert code == 0, text
    with BagReader(fixed) as rd:
        got = [int(rd.decode(m).data) for m in rd.messages()]
    # in order from the first recorded message; what was lost at the end is at most the last flush interval's
    # worth. A gap in the middle is a message that never reached the recorder (on a loaded machine the recorder's
    # process can be descheduled long enough for DDS to drop some: 4 of a 2000 Hz stream were once missing): the
    # recorder writes every message it takes, so any such gap must be among the losses it counted and printed
    # (docs/recording.md, "Lost messages")
    assert got == sorted(set(got))
    missing = got[-1] - got[0] + 1 - len(got)
    line = [ln for ln in output.splitlines() if ln.strip().startswith("/t/omega_h")][-1]
    reported = int(line.split()[3]) if line.endswith(" lost") else 0
    assert missing <= reported, (missing, line)
    assert written - len(got) <= 2000 * 0.25, (written, len(got))


def test_standalone_record_refuses_a_target_it_cannot_write(tmp_path):
    """`flagbot record -o` into a directory that does not exist: one line naming it, exit 2, nothing created."""
    from cli_helpers import flagbot
    r = flagbot("record", "-o", str(tmp_path / "typo" / "run.mcap"), timeout=60)
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"error: cannot record to {tmp_path / 'typo' / 'run.mcap'}: directory {tmp_path / 'typo'} does not exist" \
        in r.stderr and "Traceback" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_standalone_record_refuses_a_duration_that_is_not_positive(tmp_path):
    """`flagbot record --duration 0 / -1 / nan`: one `error:` line naming --duration, exit 2, no file (-1 and nan
    used to stop at once and leave an empty recording, 0 to record until Ctrl-C)."""
    from cli_helpers import flagbot
    for bad in ("0", "-1", "nan"):
        r = flagbot("record", "-o", str(tmp_path / "run.mcap"), "--duration", bad, timeout=60)
        assert r.returncode == 2, (bad, r.stdout + r.stderr)
        err = [ln for ln in r.stderr.splitlines() if ln.startswith("error")]
        assert len(err) == 1 and "--duration" in err[0] and "Traceback" not in r.stderr, (bad, r.stderr)
    assert list(tmp_path.iterdir()) == []


def test_standalone_record_refuses_a_dangling_symbolic_link(tmp_path):
    """`flagbot record -o LINK` and the `record` script with LINK -> a missing file: one `error:` line naming the
    link, exit 2, the target not created (it used to be written through the link)."""
    from cli_helpers import flagbot
    target = tmp_path / "elsewhere" / "target.mcap"
    target.parent.mkdir()
    link = tmp_path / "run.mcap"
    link.symlink_to(target)
    for cmd in (("record",), ("-m", "flagbot_sim.ros.recorder")):
        if cmd[0] == "record":
            r = flagbot("record", "-o", str(link), timeout=120)
            code, err = r.returncode, r.stderr
        else:
            p = ChildProcess(*cmd, "-o", str(link))
            code, err = p.wait(timeout=120)
        assert code == 2, err
        lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
        assert len(lines) == 1 and str(link) in lines[0] and "symbolic link" in lines[0], err
        assert "Traceback" not in err
        assert not target.exists() and link.is_symlink()
