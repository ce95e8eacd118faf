"""A full disk during a sim_node recording: one clear error in the log, an ERROR in /diagnostics that stays until
the recording is stopped, a refused new recording that cannot be written, and exit code 1 at shutdown.

The full disk is real as far as the process can tell: once sim_node runs, its file-size limit (RLIMIT_FSIZE, set
from here with prlimit) is lowered, so writes past it fail with EFBIG (CPython ignores SIGXFSZ). The node's output
goes through a pipe and its ROS log file is off (--disable-external-lib-logs): neither is a file it could not
write any more.
"""
import resource

from diagnostic_msgs.msg import DiagnosticStatus

from ros_helpers import DISCOVERY_TIMEOUT, EVENT_TIMEOUT, ChildProcess, Listener, set_params, spin_until

LIMIT = 96 * 1024       # bytes: above the header, metadata and schemas, reached within a few seconds of recording


def test_full_disk_during_recording(ros, tmp_path):
    proc = ChildProcess("-m", "flagbot_sim.ros.sim_node", "--ros-args", "--disable-external-lib-logs",
                        "-p", "scene:=design2", "-p", "real_time_factor:=5.0", "-p", "initial_omega:=5.0",
                        "-p", "marker_rate:=50.0", pipe=True)
    lis = Listener(ros)
    full = tmp_path / "full.mcap"
    try:
        spin_until(ros, lambda: len(lis.msgs["clock"]) > 5, DISCOVERY_TIMEOUT, "/clock")
        resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (LIMIT, LIMIT))
        (res,) = set_params(ros, "sim_node", record=str(full))
        assert res.successful, res.reason

        def failed(m):
            v = lis.diag_values_of(m)
            return v["_level"] == DiagnosticStatus.ERROR and "recording" in v["_message"]
        spin_until(ros, lambda: lis.msgs["diag"] and failed(lis.msgs["diag"][-1]), EVENT_TIMEOUT,
                   "a recording ERROR")
        first = len(lis.msgs["diag"]) - 1
        assert full.stat().st_size <= LIMIT
        values = lis.diag_values()
        assert values["recording"] == str(full) and values["recording_error"]
        assert str(full) in values["_message"]
        # it stays: three more diagnostics (one per wall second), all ERROR, while the node keeps running
        spin_until(ros, lambda: len(lis.msgs["diag"]) >= first + 4, EVENT_TIMEOUT, "more diagnostics")
        assert all(failed(m) for m in lis.msgs["diag"][first:])
        # a new recording the disk cannot take is refused, and the current one stays current
        resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (1, 1))
        (res,) = set_params(ros, "sim_node", record=str(tmp_path / "second.mcap"))
        assert not res.successful and "second.mcap" in res.reason, res.reason
        n = len(lis.msgs["diag"])
        spin_until(ros, lambda: len(lis.msgs["diag"]) > n, EVENT_TIMEOUT, "diagnostics")
        assert failed(lis.msgs["diag"][-1]) and lis.diag_values()["recording"] == str(full)
        # stopping the recording clears the ERROR
        (res,) = set_params(ros, "sim_node", record="")
        assert res.successful, res.reason
        # (a diagnostic issued before the change can still be on its way: wait for the first one that is OK)
        spin_until(ros, lambda: lis.msgs["diag"] and lis.diag_values()["_level"] == DiagnosticStatus.OK, EVENT_TIMEOUT,
                   "diagnostics back to OK")
        assert lis.diag_values()["recording"] == ""
        assert proc.alive()
    finally:
        lis.close()
        code, out = proc.stop()
    assert "Traceback" not in out, out
    assert code == 1, out              # the run lost data: not a success
    # one clear error line for the failure (the recorder's), not one per topic or per write
    errors = [line for line in out.splitlines() if line.startswith("[ERROR]")]
    assert len(errors) == 1 and "recording stopped" in errors[0] and str(full) in errors[0], out
    assert "too large" in errors[0].lower(), errors[0]
    assert "recording failed to write" in out
